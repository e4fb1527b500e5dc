#include "simstack/offline/eval/classical_baseline.h"

#include "simstack/instances/surface_instances.h"
#include "simstack/pipeline/workspace.h"

namespace simstack {

std::vector<Points3> clusterVisiblePoints(const DepthImage& depth, const PinholeCamera& camera,
                                          const Transform& T_table_camera,
                                          const ClassicalConfig& config, const GridSpec* crop,
                                          std::vector<std::vector<int>>* pixels) {
  camera.validate();
  if (depth.width != camera.width || depth.height != camera.height)
    throw std::invalid_argument("classical baseline: depth and camera sizes differ");
  WorkspaceConfig box;
  if (crop) {  // the x/y box of the grid, any height
    const Vec3& o = crop->origin_table;
    box.min_m = {o.x(), o.y(), -WorkspaceConfig::kUnbounded};
    box.max_m = {o.x() + crop->extent_m(), o.y() + crop->extent_m(), WorkspaceConfig::kUnbounded};
  }
  std::vector<int> pixel_of_point;
  const Points3 points =
      pilePoints(DepthView{depth, camera, T_table_camera}, T_table_camera, box, config.min_height_m,
                 WorkspaceConfig::kUnbounded, std::max(1, config.pixel_stride), &pixel_of_point);
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
