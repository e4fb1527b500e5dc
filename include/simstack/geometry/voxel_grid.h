#pragma once
/// @file voxel_grid.h
/// Axis-aligned voxel grids in the table frame (docs/design.md section 4).
/// Memory order: x fastest, then y, then z (linear = (iz * R + iy) * R + ix), so that a grid
/// maps to a C-order array [z][y][x] in HDF5, numpy and torch ([D, H, W]).

#include <cmath>
#include <stdexcept>
#include <vector>

#include "simstack/types.h"

namespace simstack {

/// Geometry of a cubic R^3 grid: origin is the minimum corner in the table frame.
struct GridSpec {
  Vec3 origin_table = Vec3::Zero();
  double voxel_size_m = 0.02;
  int resolution = 32;

  /// The scene grid (docs/design.md section 4): side `extent_m`, x/y centred on `centre_xy`, z
  /// from 0 up.
  static GridSpec sceneGrid(const Vec2& centre_xy, double extent_m, int resolution);

  int voxelCount() const { return resolution * resolution * resolution; }
  double extent_m() const { return voxel_size_m * resolution; }
  int linear(int ix, int iy, int iz) const { return (iz * resolution + iy) * resolution + ix; }
  Vec3i unravel(int linear_index) const {
    return {linear_index % resolution, (linear_index / resolution) % resolution,
            linear_index / (resolution * resolution)};
  }
  bool inside(int ix, int iy, int iz) const {
    return ix >= 0 && iy >= 0 && iz >= 0 && ix < resolution && iy < resolution && iz < resolution;
  }
  /// Centre of voxel (ix, iy, iz) in the table frame.
  Vec3 voxelCentre(int ix, int iy, int iz) const {
    return origin_table + voxel_size_m * Vec3(ix + 0.5, iy + 0.5, iz + 0.5);
  }
  /// Continuous index of a table-frame point: voxel centres sit at integer values.
  Vec3 continuousIndex(const Vec3& p_table) const {
    return (p_table - origin_table) / voxel_size_m - Vec3::Constant(0.5);
  }
  /// Index of the voxel containing the point (may be outside the grid).
  /// A point far outside (1e30 m from a bad depth pixel) or NaN gives an index just outside
  /// the grid (-2 or resolution + 1, so that its neighbours are outside too), not an int
  /// overflow.
  Vec3i voxelIndex(const Vec3& p_table) const {
    const Vec3 c = (p_table - origin_table) / voxel_size_m;
    const auto index = [this](double v) {
      if (!(v >= -2.0)) return -2;  // also NaN
      if (v >= resolution + 1.0) return resolution + 1;
      return static_cast<int>(std::floor(v));
    };
    return {index(c.x()), index(c.y()), index(c.z())};
  }
  /// True when the point lies within the grid's box.
  bool containsPoint(const Vec3& p_table) const {
    const Vec3 c = (p_table - origin_table) / voxel_size_m;
    return (c.array() >= 0.0).all() && (c.array() < resolution).all();
  }
  bool operator==(const GridSpec& o) const {
    return origin_table == o.origin_table && voxel_size_m == o.voxel_size_m &&
           resolution == o.resolution;
  }
};

/// A dense scalar or vector field on a GridSpec.
template <typename T>
struct Grid3 {
  GridSpec spec;
  std::vector<T> data;

  Grid3() = default;
  Grid3(const GridSpec& s, const T& fill) : spec(s), data(s.voxelCount(), fill) {}

  T& at(int ix, int iy, int iz) { return data[spec.linear(ix, iy, iz)]; }
  const T& at(int ix, int iy, int iz) const { return data[spec.linear(ix, iy, iz)]; }

  /// Trilinear interpolation at a table-frame point; indices are clamped to the grid, so
  /// points outside take the value of the nearest boundary voxels.
  T sampleTrilinear(const Vec3& p_table) const {
    const Vec3 c = spec.continuousIndex(p_table);
    const int r = spec.resolution;
    auto clampi = [r](int i) { return i < 0 ? 0 : (i >= r ? r - 1 : i); };
    const int x0 = static_cast<int>(std::floor(c.x()));
    const int y0 = static_cast<int>(std::floor(c.y()));
    const int z0 = static_cast<int>(std::floor(c.z()));
    double fx = c.x() - x0, fy = c.y() - y0, fz = c.z() - z0;
    const int xa = clampi(x0), xb = clampi(x0 + 1), ya = clampi(y0), yb = clampi(y0 + 1),
              za = clampi(z0), zb = clampi(z0 + 1);
    auto lerp = [](const T& a, const T& b, double t) { return a + (b - a) * t; };
    const T c00 = lerp(at(xa, ya, za), at(xb, ya, za), fx);
    const T c10 = lerp(at(xa, yb, za), at(xb, yb, za), fx);
    const T c01 = lerp(at(xa, ya, zb), at(xb, ya, zb), fx);
    const T c11 = lerp(at(xa, yb, zb), at(xb, yb, zb), fx);
    return lerp(lerp(c00, c10, fy), lerp(c01, c11, fy), fz);
  }
};

}  // namespace simstack
