#pragma once
/// @file projective_tsdf.h
/// The partial TSDF that conditions the network (paper section 3.1.2): projective signed
/// distances from one or more depth images, fused KinectFusion-style with a weight per voxel.

#include "simstack/geometry/image.h"
#include "simstack/geometry/pinhole_camera.h"
#include "simstack/geometry/voxel_grid.h"

namespace simstack {

struct ProjectiveTsdfConfig {
  double truncation_m = 0.06;  ///< tau; 3 voxels by default (docs/design.md section 4)
  float max_weight = 64.0f;    ///< fusion weight cap
  /// Value of never-observed voxels: unknown space behind surfaces may be solid, so it reads
  /// as -tau; the weight channel (0) tells it apart from observed solid.
  bool unobserved_as_occupied = true;
};

/// Not thread-safe; integrate() itself uses OpenMP over z slices.
class ProjectiveTsdf {
 public:
  ProjectiveTsdf(const GridSpec& grid, const ProjectiveTsdfConfig& config = ProjectiveTsdfConfig());

  /// Fuses one depth image (m; NaN, inf or <= 0 = missing). Throws std::invalid_argument when
  /// the image size does not match the camera or the camera is invalid.
  void integrate(const DepthImage& depth, const PinholeCamera& camera,
                 const Transform& T_table_camera);
  void reset();

  const GridSpec& grid() const { return tsdf_.spec; }
  /// Signed distance in metres within +-truncation_m.
  const Grid3<float>& tsdf() const { return tsdf_; }
  /// Number of observations fused into each voxel (0 = never observed).
  const Grid3<float>& weight() const { return weight_; }
  double truncation_m() const { return config_.truncation_m; }

 private:
  ProjectiveTsdfConfig config_;
  Grid3<float> tsdf_;
  Grid3<float> weight_;
};

}  // namespace simstack
