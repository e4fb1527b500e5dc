#include "simstack/pipeline/classical_baseline.h"

#include <pcl/point_types.h>
#include <pcl/search/kdtree.h>
#include <pcl/segmentation/extract_clusters.h>

namespace simstack {

std::vector<Points3> clusterVisiblePoints(const DepthImage& depth, const PinholeCamera& camera,
                                          const Transform& T_table_camera,
                                          const ClassicalConfig& config, const GridSpec* crop) {
  camera.validate();
  if (depth.width != camera.width || depth.height != camera.height)
    throw std::invalid_argument("classical baseline: depth and camera sizes differ");
  pcl::PointCloud<pcl::PointXYZ>::Ptr cloud(new pcl::PointCloud<pcl::PointXYZ>);
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
      cloud->push_back(pcl::PointXYZ(p.x(), p.y(), p.z()));
    }
  std::vector<Points3> clusters;
  if (cloud->size() < static_cast<size_t>(config.min_cluster_points)) return clusters;
  pcl::search::KdTree<pcl::PointXYZ>::Ptr tree(new pcl::search::KdTree<pcl::PointXYZ>);
  tree->setInputCloud(cloud);
  pcl::EuclideanClusterExtraction<pcl::PointXYZ> ec;
  ec.setClusterTolerance(config.cluster_tolerance_m);
  ec.setMinClusterSize(config.min_cluster_points);
  ec.setMaxClusterSize(static_cast<int>(cloud->size()));
  ec.setSearchMethod(tree);
  ec.setInputCloud(cloud);
  std::vector<pcl::PointIndices> found;
  ec.extract(found);
  for (const auto& idx : found) {
    Points3 pts;
    for (int i : idx.indices) pts.emplace_back((*cloud)[i].x, (*cloud)[i].y, (*cloud)[i].z);
    clusters.push_back(std::move(pts));
  }
  return clusters;
}

std::vector<SuperquadricShape> classicalBaseline(const DepthImage& depth,
                                                 const PinholeCamera& camera,
                                                 const Transform& T_table_camera,
                                                 const ClassicalConfig& config,
                                                 const GridSpec* crop) {
  const std::vector<Points3> clusters =
      clusterVisiblePoints(depth, camera, T_table_camera, config, crop);
  FitConfig fit = config.fit;
  fit.threads = std::max(1, config.threads);
  std::vector<SuperquadricShape> out;
  for (const auto& f :
       fitInstances(clusters, fit, config.joint_refinement, config.min_cluster_points))
    if (f) out.push_back(*f);
  return out;
}

}  // namespace simstack
