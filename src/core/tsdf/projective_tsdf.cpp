#include "simstack/tsdf/projective_tsdf.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace simstack {

ProjectiveTsdf::ProjectiveTsdf(const GridSpec& grid, const ProjectiveTsdfConfig& config)
    : config_(config) {
  if (!(config.truncation_m > 0.0)) throw std::invalid_argument("TSDF truncation must be > 0 m");
  tsdf_ = Grid3<float>(grid, 0.0f);
  weight_ = Grid3<float>(grid, 0.0f);
  reset();
}

void ProjectiveTsdf::reset() {
  std::fill(tsdf_.data.begin(), tsdf_.data.end(),
            config_.unobserved_as_occupied ? -static_cast<float>(config_.truncation_m) : 0.0f);
  std::fill(weight_.data.begin(), weight_.data.end(), 0.0f);
}

void ProjectiveTsdf::integrate(const DepthImage& depth, const PinholeCamera& camera,
                               const Transform& T_table_camera) {
  camera.validate();
  if (depth.width != camera.width || depth.height != camera.height) {
    throw std::invalid_argument("depth image is " + std::to_string(depth.width) + "x" +
                                std::to_string(depth.height) + " but the camera is " +
                                std::to_string(camera.width) + "x" + std::to_string(camera.height));
  }
  const GridSpec& g = tsdf_.spec;
  const int r = g.resolution;
  const Transform T_camera_table = T_table_camera.inverse();
  const Eigen::Matrix3f R = T_camera_table.linear().cast<float>();
  const Eigen::Vector3f step_x = R.col(0) * static_cast<float>(g.voxel_size_m);
  const float tau = static_cast<float>(config_.truncation_m);
  const float fx = camera.fx, fy = camera.fy, cx = camera.cx, cy = camera.cy;
  const int w = depth.width, h = depth.height;
  const float max_weight = config_.max_weight;
#pragma omp parallel for schedule(static)
  for (int iz = 0; iz < r; ++iz) {
    for (int iy = 0; iy < r; ++iy) {
      // Walk the row in the camera frame: one matrix product per row, additions per voxel.
      Eigen::Vector3f p = (T_camera_table * g.voxelCentre(0, iy, iz)).cast<float>();
      float* tsdf = &tsdf_.data[g.linear(0, iy, iz)];
      float* weight = &weight_.data[g.linear(0, iy, iz)];
      for (int ix = 0; ix < r; ++ix, p += step_x) {
        if (p.z() <= 1e-6f) continue;
        const float inv_z = 1.0f / p.z();
        // Compared as the long lround gives: a voxel just in front of the camera plane projects
        // beyond any int, which a narrowing first would wrap back into the image.
        const long u = std::lround(fx * p.x() * inv_z + cx);
        const long v = std::lround(fy * p.y() * inv_z + cy);
        if (u < 0 || v < 0 || u >= w || v >= h) continue;
        const float d = depth.pixels[static_cast<size_t>(v) * w + u];
        if (!(d > 0.0f) || !std::isfinite(d)) continue;
        // Distance along the viewing ray: depth difference times the ray length per unit z.
        const float sdf = (d - p.z()) * p.norm() * inv_z;
        if (sdf < -tau) continue;  // hidden behind the observed surface
        const float value = std::min(sdf, tau);
        const float w_old = weight[ix];
        tsdf[ix] = w_old > 0.0f ? (w_old * tsdf[ix] + value) / (w_old + 1.0f) : value;
        weight[ix] = std::min(w_old + 1.0f, max_weight);
      }
    }
  }
}

}  // namespace simstack
