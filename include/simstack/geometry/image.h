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

}  // namespace simstack
