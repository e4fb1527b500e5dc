#include "simstack/offline/eval/classical_baseline.h"

#include "simstack/instances/surface_instances.h"

namespace simstack {

std::vector<Points3> clusterVisiblePoints(const DepthImage& depth, const PinholeCamera& camera,
                                          const Transform& T_table_camera,
                                          const ClassicalConfig& config, const GridSpec* crop,
                                          std::vector<std::vector<int>>* pixels) {
  camera.validate();
  if (depth.width != camera.width || depth.height != camera.height)
    throw std::invalid_argument("classical baseline: depth and camera sizes differ");
  Points3 points;
  std::vector<int> pixel_of_point;
  const int stride = std::max(1, config.pixel_stride);
  for (int v = 0; v < depth.height; v += stride)
    for (int u = 0; u < depth.width; u += stride) {
      const float d = depth.at(u, v);
      if (!validDepth(d)) continue;
      const Vec3 p = T_table_camera * camera.backproject(u, v, d);
      if (p.z() < config.min_height_m) continue;
      if (crop) {  // the x/y box of the grid, any height
        const Vec3 rel = p - crop->origin_table;
        if (rel.x() < 0 || rel.y() < 0 || rel.x() >= crop->extent_m() ||
            rel.y() >= crop->extent_m())
          continue;
      }
      points.push_back(p);
      pixel_of_point.push_back(v * depth.width + u);
    }
  std::vector<Points3> clusters;
  if (pixels) pixels->clear();
  for (const std::vector<int>& idx :
       euclideanClusters(points, config.cluster_tolerance_m, config.min_cluster_points)) {
    Points3 pts;
    for (int i : idx) pts.push_back(points[i]);
    clusters.push_back(std::move(pts));
    if (!pixels) continue;
    pixels->emplace_back();
    for (int i : idx) pixels->back().push_back(pixel_of_point[i]);
  }
  return clusters;
}

std::vector<SuperquadricShape> classicalBaseline(
    const DepthImage& depth, const PinholeCamera& camera, const Transform& T_table_camera,
    const ClassicalConfig& config, const GridSpec* crop, Image<int>* pixel_instances) {
  std::vector<std::vector<int>> pixels;
  const std::vector<Points3> clusters = clusterVisiblePoints(
      depth, camera, T_table_camera, config, crop, pixel_instances ? &pixels : nullptr);
  if (pixel_instances) *pixel_instances = Image<int>(depth.width, depth.height, -1);
  FitConfig fit = config.fit;
  fit.threads = std::max(1, config.threads);
  std::vector<SuperquadricShape> out;
  const auto fits = fitInstances(clusters, fit, config.joint_refinement, config.min_cluster_points);
  for (size_t k = 0; k < fits.size(); ++k) {
    if (!fits[k]) continue;
    if (pixel_instances)
      for (int i : pixels[k]) pixel_instances->pixels[i] = static_cast<int>(out.size());
    out.push_back(*fits[k]);
  }
  return out;
}

}  // namespace simstack
