#include "simstack/pipeline/table_plane.h"

#include <pcl/ModelCoefficients.h>
#include <pcl/point_types.h>
#include <pcl/sample_consensus/method_types.h>
#include <pcl/sample_consensus/model_types.h>
#include <pcl/segmentation/sac_segmentation.h>

#include <stdexcept>
#include <string>

namespace simstack {

TablePlane estimateTablePlane(const DepthImage& depth, const PinholeCamera& camera,
                              const TablePlaneConfig& config) {
  camera.validate();
  if (depth.width != camera.width || depth.height != camera.height ||
      depth.pixels.size() != static_cast<size_t>(depth.width) * depth.height)
    throw std::invalid_argument("table plane: the depth image is " + std::to_string(depth.width) +
                                "x" + std::to_string(depth.height) + " but the camera is " +
                                std::to_string(camera.width) + "x" + std::to_string(camera.height));
  pcl::PointCloud<pcl::PointXYZ>::Ptr cloud(new pcl::PointCloud<pcl::PointXYZ>);
  const int stride = std::max(1, config.pixel_stride);
  for (int v = 0; v < depth.height; v += stride)
    for (int u = 0; u < depth.width; u += stride) {
      const float d = depth.at(u, v);
      if (!validDepth(d) || d > config.max_depth_m) continue;
      const Vec3 p = camera.backproject(u, v, d);
      cloud->push_back(pcl::PointXYZ(p.x(), p.y(), p.z()));
    }
  if (cloud->size() < 50)
    throw std::runtime_error("table plane: only " + std::to_string(cloud->size()) +
                             " valid depth points; cannot estimate the table");
  pcl::SACSegmentation<pcl::PointXYZ> seg;
  seg.setOptimizeCoefficients(true);
  seg.setModelType(pcl::SACMODEL_PLANE);
  seg.setMethodType(pcl::SAC_RANSAC);
  seg.setDistanceThreshold(config.inlier_distance_m);
  seg.setMaxIterations(config.max_iterations);
  seg.setInputCloud(cloud);
  pcl::PointIndices inliers;
  pcl::ModelCoefficients coefficients;
  seg.segment(inliers, coefficients);
  TablePlane out;
  out.points = static_cast<int>(cloud->size());
  out.inliers = static_cast<int>(inliers.indices.size());
  if (coefficients.values.size() != 4 || out.inliers < config.min_inlier_share * out.points)
    throw std::runtime_error("table plane: no dominant plane in the depth image (" +
                             std::to_string(out.inliers) + " of " + std::to_string(out.points) +
                             " points on the best plane)");
  Vec3 n(coefficients.values[0], coefficients.values[1], coefficients.values[2]);
  double d = coefficients.values[3];
  const double norm = n.norm();
  n /= norm;
  d /= norm;
  if (d < 0) {  // the camera (origin) must be on the positive side
    n = -n;
    d = -d;
  }
  out.plane_camera << n, d;
  Vec3 x = Vec3::UnitX() - Vec3::UnitX().dot(n) * n;
  if (x.norm() < 1e-6) x = Vec3::UnitY() - Vec3::UnitY().dot(n) * n;
  x.normalize();
  Transform T_camera_table = Transform::Identity();
  T_camera_table.linear().col(0) = x;
  T_camera_table.linear().col(1) = n.cross(x);
  T_camera_table.linear().col(2) = n;
  T_camera_table.translation() = -d * n;
  out.T_table_camera = T_camera_table.inverse();
  return out;
}

}  // namespace simstack
