#include "simstack/tsdf/network_input.h"

#include <algorithm>

namespace simstack {

Vec2 visiblePileCentre(const DepthImage& depth, const PinholeCamera& camera,
                       const Transform& T_table_camera, const Vec2& near_xy, double radius_m,
                       double min_height_m) {
  Vec2 sum = Vec2::Zero();
  long n = 0;
  for (int v = 0; v < depth.height; ++v) {
    for (int u = 0; u < depth.width; ++u) {
      const float d = depth.at(u, v);
      if (!validDepth(d)) continue;
      const Vec3 p = T_table_camera * camera.backproject(u, v, d);
      if (p.z() < min_height_m || (p.head<2>() - near_xy).norm() > radius_m) continue;
      sum += p.head<2>();
      ++n;
    }
  }
  return n > 0 ? Vec2(sum / static_cast<double>(n)) : near_xy;
}

std::vector<float> partialChannels(const Grid3<float>& tsdf_m, const Grid3<float>& weight,
                                   double truncation_m) {
  const size_t n = tsdf_m.data.size();
  std::vector<float> out(2 * n);
  const float inv_tau = static_cast<float>(1.0 / truncation_m);
  for (size_t i = 0; i < n; ++i) {
    out[i] = std::clamp(tsdf_m.data[i] * inv_tau, -1.0f, 1.0f);
    out[n + i] = weight.data[i] > 0.0f ? 1.0f : 0.0f;
  }
  return out;
}

}  // namespace simstack
