#pragma once
/// @file ground_truth.h
/// Ground-truth grids of a scene (docs/design.md section 4): full TSDF, centre votes, instance
/// labels.

#include <cstdint>
#include <memory>

#include "simstack/geometry/voxel_grid.h"
#include "simstack/scene/scene.h"

namespace simstack {

struct GroundTruthGrids {
  Grid3<float> tsdf;      ///< signed distance to the nearest object surface (m), +-truncation
  Grid3<Vec3f> votes;     ///< inside object k: unit vector from the voxel centre to k's centroid
  Grid3<uint8_t> labels;  ///< 0 = free, k = inside object k (1-based scene order)
};

/// Signed distance (m) of a table-frame point to the union of the scene's objects, truncated
/// at +-truncation_m; `label` receives the containing object (1-based) or 0.
/// Distances come from dense surface samples: the point-to-tangent-plane distance of the
/// nearest sample within three sample spacings of the surface, the point-to-sample distance
/// beyond (error well under a millimetre either way). Signs come from the exact inside test.
class SceneDistanceField {
 public:
  SceneDistanceField(const Scene& scene, double truncation_m);
  ~SceneDistanceField();
  float signedDistance(const Vec3& p_table, uint8_t* label = nullptr) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Fills the three grids on `grid`. Throws std::invalid_argument for more than 254 objects.
GroundTruthGrids computeGroundTruth(const Scene& scene, const GridSpec& grid, double truncation_m);

}  // namespace simstack
