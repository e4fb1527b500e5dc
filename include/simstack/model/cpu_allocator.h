#pragma once
/// @file cpu_allocator.h
/// Process-wide allocator settings for running libtorch on the CPU.

namespace simstack {

/// libtorch's CPU allocator does not cache: with glibc's defaults every large tensor is a fresh
/// mmap that page-faults on first touch (about 30 % system time in training). This keeps freed
/// memory in the heap for reuse instead (no mmap for large blocks, no trimming: training 1.45x
/// faster at R = 64; docs/experiments.md, "Runtime (threads, allocator)"). It changes glibc's
/// malloc for the whole process, so programs call it once at the start of main(); a library
/// never does it on its own.
void keepFreedMemoryForReuse();

}  // namespace simstack
