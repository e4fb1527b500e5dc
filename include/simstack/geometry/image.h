#pragma once
/// @file image.h
/// A minimal row-major image, so that the core needs no OpenCV type in its interfaces.

#include <cstddef>
#include <cstdint>
#include <limits>
#include <vector>

namespace simstack {

template <typename T>
struct Image {
  int width = 0;
  int height = 0;
  std::vector<T> pixels;  // row-major, pixels[v * width + u]

  Image() = default;
  Image(int w, int h, T fill) : width(w), height(h), pixels(static_cast<size_t>(w) * h, fill) {}
  T& at(int u, int v) { return pixels[static_cast<size_t>(v) * width + u]; }
  const T& at(int u, int v) const { return pixels[static_cast<size_t>(v) * width + u]; }
  bool empty() const { return pixels.empty(); }
};

/// Depth along the optical axis in metres; NaN or <= 0 marks a missing measurement.
using DepthImage = Image<float>;
/// Instance mask: 0 = table, k >= 1 = object k, kNoSurface where the ray hit nothing.
using InstanceImage = Image<uint8_t>;
constexpr uint8_t kNoSurface = 255;

inline bool validDepth(float d) { return d > 0.0f && d < std::numeric_limits<float>::infinity(); }

/// Where a walk of the image every `stride` pixels starts: pixel (0, 0), unless that lattice
/// holds under half its share of the valid depth (holes in step with the stride, as in a depth
/// image registered into a frame twice its size); then the start in [0, stride)^2 whose lattice
/// holds the most.
struct LatticeStart {
  int u = 0;
  int v = 0;
};
inline LatticeStart latticeStart(const DepthImage& depth, int stride) {
  if (stride <= 1) return {};
  std::vector<size_t> count(static_cast<size_t>(stride) * stride, 0);
  size_t valid = 0;
  for (int v = 0; v < depth.height; ++v)
    for (int u = 0; u < depth.width; ++u)
      if (validDepth(depth.at(u, v))) {
        ++valid;
        ++count[static_cast<size_t>(v % stride) * stride + u % stride];
      }
  if (2 * count[0] * count.size() >= valid) return {};
  size_t best = 0;
  for (size_t k = 1; k < count.size(); ++k)
    if (count[k] > count[best]) best = k;
  return {static_cast<int>(best % stride), static_cast<int>(best / stride)};
}

}  // namespace simstack
