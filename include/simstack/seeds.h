#pragma once
/// @file seeds.h
/// Deriving independent random-stream seeds from a seed and an index.

#include <cstdint>

namespace simstack {

/// SplitMix64's output function: spreads the bits of `z` (a seed combined with an index by the
/// caller) so that neighbouring inputs give unrelated streams.
inline uint64_t splitMix64(uint64_t z) {
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

}  // namespace simstack
