#pragma once
/// @file scene_metrics.h
/// Scene-level measures of the paper's section 4.1: Chamfer distance between surface samples
/// (eq. 7), visible surfaces, occupancy of superquadric scenes, and stability under physics.

#include <random>
#include <vector>

#include "simstack/geometry/pinhole_camera.h"
#include "simstack/geometry/superquadric.h"
#include "simstack/geometry/triangle_mesh.h"
#include "simstack/geometry/voxel_grid.h"
#include "simstack/mesh/mesh_ops.h"
#include "simstack/offline/piles/pile_generator.h"
#include "simstack/render/visibility.h"
#include "simstack/scene/scene.h"

namespace simstack {

/// Eq. 7: mean nearest-neighbour distance from a to b plus from b to a (metres). Infinite
/// when either set is empty.
double chamferDistance(const Points3& a, const Points3& b);

/// Signed occupancy of shapes at the voxel centres of `grid`: -1 inside any shape, +1 outside
/// (a TSDF sign, for scoreOccupancy).
std::vector<float> superquadricOccupancy(const std::vector<SuperquadricShape>& shapes,
                                         const GridSpec& grid);

/// The protocol of docs/design.md section 6: the shapes as rigid bodies of uniform density on the
/// table, 10,000 steps, gravity 10 m/s^2, friction 1. Rolling and spinning friction are those
/// of the physics that settled and verified the generated piles (sleeping stays on, which the
/// generator turns off): with the physics' default of 0.001, rounded objects of the true piles
/// themselves roll away during the 42 s.
struct StabilityConfig {
  int steps = 10000;
  double gravity_mps2 = 10.0;
  double friction = 1.0;
  double rolling_friction = PileConfig::generationPhysics().rolling_friction;
  double spinning_friction = PileConfig::generationPhysics().spinning_friction;
  double max_displacement_m = 0.2;                ///< a pile is stable when no centre moves further
  double max_rotation_rad = 30.0 * M_PI / 180.0;  ///< and no object turns more
};
struct StabilityResult {
  double mean_displacement_m = 0.0;
  double max_displacement_m = 0.0;
  double max_rotation_rad = 0.0;
  bool stable = true;
};
StabilityResult simulateStability(const std::vector<SuperquadricShape>& shapes,
                                  const StabilityConfig& config = StabilityConfig());
/// The same test for any scene (e.g. a generated pile of superquadrics or meshes, as the
/// reference that predictions are held against).
StabilityResult simulateStability(const Scene& scene,
                                  const StabilityConfig& config = StabilityConfig());

}  // namespace simstack
