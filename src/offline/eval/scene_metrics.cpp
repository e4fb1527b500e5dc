#include "simstack/offline/eval/scene_metrics.h"

#include <cmath>
#include <limits>
#include <memory>
#include <nanoflann.hpp>
#include <stdexcept>

#include "simstack/physics/physics_world.h"
#include "simstack/render/depth_renderer.h"
#include "simstack/scene/scene.h"

namespace simstack {
namespace {

struct PointSet {
  const Points3* pts;
  size_t kdtree_get_point_count() const { return pts->size(); }
  double kdtree_get_pt(size_t i, size_t d) const { return (*pts)[i][d]; }
  template <class B>
  bool kdtree_get_bbox(B&) const {
    return false;
  }
};
using Tree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<double, PointSet>,
                                                 PointSet, 3>;

double meanNearest(const Points3& from, const Points3& to) {
  PointSet set{&to};
  Tree tree(3, set, nanoflann::KDTreeSingleIndexAdaptorParams(10));
  tree.buildIndex();
  double sum = 0;
  for (const Vec3& p : from) {
    size_t index;
    double d2;
    nanoflann::KNNResultSet<double> result(1);
    result.init(&index, &d2);
    tree.findNeighbors(result, p.data(), nanoflann::SearchParams());
    sum += std::sqrt(d2);
  }
  return sum / from.size();
}

}  // namespace

double chamferDistance(const Points3& a, const Points3& b) {
  if (a.empty() || b.empty()) return std::numeric_limits<double>::infinity();
  return meanNearest(a, b) + meanNearest(b, a);
}

std::vector<float> superquadricOccupancy(const std::vector<SuperquadricShape>& shapes,
                                         const GridSpec& grid) {
  std::vector<float> out(grid.voxelCount(), 1.0f);
  for (const SuperquadricShape& sq : shapes) {
    const double reach = sq.scale_m.maxCoeff() * std::sqrt(3.0);
    const Vec3i lo = grid.voxelIndex(sq.centroid() - Vec3::Constant(reach));
    const Vec3i hi = grid.voxelIndex(sq.centroid() + Vec3::Constant(reach));
    for (int z = std::max(0, lo.z()); z <= std::min(grid.resolution - 1, hi.z()); ++z)
      for (int y = std::max(0, lo.y()); y <= std::min(grid.resolution - 1, hi.y()); ++y)
        for (int x = std::max(0, lo.x()); x <= std::min(grid.resolution - 1, hi.x()); ++x)
          if (sq.contains(grid.voxelCentre(x, y, z))) out[grid.linear(x, y, z)] = -1.0f;
  }
  return out;
}

StabilityResult simulateStability(const Scene& scene, const StabilityConfig& config) {
  StabilityResult r;
  if (scene.objects.empty()) return r;
  PhysicsConfig pc;
  pc.gravity_mps2 = config.gravity_mps2;
  pc.friction = config.friction;
  pc.rolling_friction = config.rolling_friction;
  pc.spinning_friction = config.spinning_friction;
  PhysicsWorld world(pc);
  for (const SceneObject& o : scene.objects)
    world.addConvexObject(o.shape->hullPoints(), o.shape->volume(), o.T_table_object);
  world.step(config.steps);
  double sum = 0;
  for (size_t i = 0; i < scene.objects.size(); ++i) {
    const Transform& start = scene.objects[i].T_table_object;
    const Transform end = world.pose(static_cast<int>(i));
    double d = (end.translation() - start.translation()).norm();
    const double angle = Eigen::AngleAxisd(start.linear().transpose() * end.linear()).angle();
    if (!std::isfinite(d)) d = std::numeric_limits<double>::infinity();
    sum += d;
    r.max_displacement_m = std::max(r.max_displacement_m, d);
    r.max_rotation_rad = std::max(r.max_rotation_rad, angle);
  }
  r.mean_displacement_m = sum / scene.objects.size();
  r.stable = r.max_displacement_m <= config.max_displacement_m &&
             r.max_rotation_rad <= config.max_rotation_rad;
  return r;
}

StabilityResult simulateStability(const std::vector<SuperquadricShape>& shapes,
                                  const StabilityConfig& config) {
  return simulateStability(Scene::fromSuperquadrics(shapes), config);
}

}  // namespace simstack
