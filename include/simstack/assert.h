#pragma once
/// @file assert.h
/// SIMSTACK_ASSERT(condition, message) states an invariant that simstack's own code keeps: a
/// programmer error, never bad input (bad input is reported by a documented exception or a
/// status). A broken invariant stops the process with the file, line and message. It stays on
/// in Release builds, the build type by default, because the invariants it guards protect
/// memory: a write through an index or pointer the invariant makes valid.

#include <cstdio>
#include <cstdlib>

namespace simstack {

[[noreturn]] inline void assertionFailed(const char* condition, const char* message,
                                         const char* file, int line) {
  std::fprintf(stderr, "%s:%d: simstack internal error: %s (%s is false)\n", file, line, message,
               condition);
  std::fflush(stderr);
  std::abort();
}

}  // namespace simstack

#define SIMSTACK_ASSERT(condition, message)                                                 \
  do {                                                                                      \
    if (!(condition)) ::simstack::assertionFailed(#condition, message, __FILE__, __LINE__); \
  } while (false)
