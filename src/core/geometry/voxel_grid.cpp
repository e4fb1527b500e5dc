#include "simstack/geometry/voxel_grid.h"

#include <string>

namespace simstack {

GridSpec GridSpec::sceneGrid(const Vec2& centre_xy, double extent_m, int resolution) {
  if (resolution < 2)
    throw std::invalid_argument("grid resolution must be >= 2, got " + std::to_string(resolution));
  if (!(extent_m > 0.0))
    throw std::invalid_argument("grid extent must be > 0 m, got " + std::to_string(extent_m));
  GridSpec g;
  g.resolution = resolution;
  g.voxel_size_m = extent_m / resolution;
  g.origin_table = Vec3(centre_xy.x() - 0.5 * extent_m, centre_xy.y() - 0.5 * extent_m, 0.0);
  return g;
}

}  // namespace simstack
