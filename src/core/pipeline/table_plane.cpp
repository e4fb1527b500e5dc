#include "simstack/pipeline/table_plane.h"

#include <pcl/ModelCoefficients.h>
#include <pcl/point_types.h>
#include <pcl/sample_consensus/method_types.h>
#include <pcl/sample_consensus/model_types.h>
#include <pcl/segmentation/sac_segmentation.h>

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

namespace simstack {

namespace {

using Cloud = pcl::PointCloud<pcl::PointXYZ>;

/// The table frame of a plane n.p + d = 0 (camera frame, n towards the camera).
Transform tableFromPlane(Vec3 n, double d) {
  Vec3 x = Vec3::UnitX() - Vec3::UnitX().dot(n) * n;
  if (x.norm() < 1e-6) x = Vec3::UnitY() - Vec3::UnitY().dot(n) * n;
  x.normalize();
  Transform T_camera_table = Transform::Identity();
  T_camera_table.linear().col(0) = x;
  T_camera_table.linear().col(1) = n.cross(x);
  T_camera_table.linear().col(2) = n;
  T_camera_table.translation() = -d * n;
  return T_camera_table.inverse();
}

struct Plane {
  Eigen::Vector4d coefficients = Eigen::Vector4d::Zero();  // normalised, camera on + side
  pcl::PointIndices inliers;
  int points = 0;  // of the cloud it was found in
};

/// The largest plane through `cloud` (PCL RANSAC), oriented towards the camera; no inliers when
/// none.
Plane largestPlane(const Cloud::Ptr& cloud, const TablePlaneConfig& config) {
  Plane out;
  out.points = static_cast<int>(cloud->size());
  if (cloud->size() < 3) return out;
  pcl::SACSegmentation<pcl::PointXYZ> seg;
  seg.setOptimizeCoefficients(true);
  seg.setModelType(pcl::SACMODEL_PLANE);
  seg.setMethodType(pcl::SAC_RANSAC);
  seg.setDistanceThreshold(config.inlier_distance_m);
  seg.setMaxIterations(config.max_iterations);
  seg.setInputCloud(cloud);
  pcl::ModelCoefficients coefficients;
  seg.segment(out.inliers, coefficients);
  if (coefficients.values.size() != 4) {
    out.inliers.indices.clear();
    return out;
  }
  for (int i = 0; i < 4; ++i) out.coefficients[i] = coefficients.values[i];
  out.coefficients /= out.coefficients.head<3>().norm();
  if (out.coefficients[3] < 0) out.coefficients = -out.coefficients;
  return out;
}

/// Share of the points inside the workspace's x/y footprint (in the frame the plane defines)
/// that lie more than `margin` behind the plane (away from the camera), where the camera
/// cannot see when the plane is the table.
double behindShare(const Cloud& cloud, const Eigen::Vector4d& plane,
                   const WorkspaceConfig& workspace, double margin) {
  const Transform T = tableFromPlane(plane.head<3>(), plane[3]);
  size_t within = 0, behind = 0;
  for (const pcl::PointXYZ& q : cloud) {
    const Vec3 p = T * Vec3(q.x, q.y, q.z);
    if (!(p.x() >= workspace.min_m[0] && p.x() <= workspace.max_m[0] &&
          p.y() >= workspace.min_m[1] && p.y() <= workspace.max_m[1]))
      continue;
    ++within;
    behind += p.z() < -margin;
  }
  return within == 0 ? 1.0 : static_cast<double>(behind) / within;
}

/// The largest plane; with a bounded workspace, the largest of the `max_planes` largest with
/// almost nothing seen behind it inside the workspace's footprint (the top of a robot's base
/// at the workspace's edge has the table behind it), re-estimated from the points inside the
/// workspace.
Plane tablePlane(const Cloud::Ptr& cloud, const TablePlaneConfig& config,
                 const WorkspaceConfig& workspace) {
  Plane first = largestPlane(cloud, config);
  if (!workspace.bounded()) return first;
  Cloud::Ptr rest(new Cloud(*cloud));
  for (int k = 0; k < std::max(1, config.max_planes); ++k) {
    const Plane plane = k == 0 ? first : largestPlane(rest, config);
    if (plane.inliers.indices.size() < config.min_inlier_share * cloud->size()) break;
    if (behindShare(*cloud, plane.coefficients, workspace, 2.0 * config.inlier_distance_m) <=
        config.max_behind_share) {
      const Transform T = tableFromPlane(plane.coefficients.head<3>(), plane.coefficients[3]);
      Cloud::Ptr inside(new Cloud);
      for (const pcl::PointXYZ& p : *cloud)
        if (workspace.contains(T * Vec3(p.x, p.y, p.z))) inside->push_back(p);
      // Kept only when it is the same table, refined (a box top inside could be larger).
      const Plane again = largestPlane(inside, config);
      const bool same =
          again.inliers.indices.size() >= 50 &&
          again.coefficients.head<3>().dot(plane.coefficients.head<3>()) > std::cos(0.05) &&
          std::abs(again.coefficients[3] - plane.coefficients[3]) < config.inlier_distance_m;
      return same ? again : plane;
    }
    Cloud::Ptr next(new Cloud);
    std::vector<bool> on(rest->size(), false);
    for (int i : plane.inliers.indices) on[i] = true;
    for (size_t i = 0; i < rest->size(); ++i)
      if (!on[i]) next->push_back((*rest)[i]);
    rest = next;
  }
  return first;
}

}  // namespace

void TablePlaneConfig::validate() const {
  const auto require = [](bool ok, const char* field, auto value, const char* range) {
    if (ok) return;
    std::ostringstream text;
    text << "table: " << field << " must be " << range << ", not " << value;
    throw std::invalid_argument(text.str());
  };
  require(std::isfinite(inlier_distance_m) && inlier_distance_m > 0 && inlier_distance_m <= 1,
          "inlier_distance_m", inlier_distance_m, "in (0, 1] m");
  require(max_iterations >= 1, "max_iterations", max_iterations, ">= 1");
  require(pixel_stride >= 1, "pixel_stride", pixel_stride, ">= 1");
  require(std::isfinite(max_depth_m) && max_depth_m > 0, "max_depth_m", max_depth_m,
          "a positive number of metres");
  require(min_inlier_share >= 0 && min_inlier_share <= 1, "min_inlier_share", min_inlier_share,
          "in [0, 1]");
  require(max_planes >= 1, "max_planes", max_planes, ">= 1");
  require(max_behind_share >= 0 && max_behind_share <= 1, "max_behind_share", max_behind_share,
          "in [0, 1]");
}

TablePlane estimateTablePlane(const DepthImage& depth, const PinholeCamera& camera,
                              const TablePlaneConfig& config, const WorkspaceConfig& workspace) {
  camera.validate();
  config.validate();
  if (depth.width != camera.width || depth.height != camera.height ||
      depth.pixels.size() != static_cast<size_t>(depth.width) * depth.height)
    throw std::invalid_argument("table plane: the depth image is " + std::to_string(depth.width) +
                                "x" + std::to_string(depth.height) + " but the camera is " +
                                std::to_string(camera.width) + "x" + std::to_string(camera.height));
  const auto usable = [&](int u, int v) {
    const float d = depth.at(u, v);
    return validDepth(d) && d <= config.max_depth_m;
  };
  const auto add = [&](Cloud* cloud, int u, int v) {
    const Vec3 p = camera.backproject(u, v, depth.at(u, v));
    cloud->push_back(pcl::PointXYZ(p.x(), p.y(), p.z()));
  };
  Cloud::Ptr cloud(new Cloud);
  size_t valid = 0;
  for (int v = 0; v < depth.height; ++v)
    for (int u = 0; u < depth.width; ++u) {
      if (!usable(u, v)) continue;
      ++valid;
      if (u % config.pixel_stride == 0 && v % config.pixel_stride == 0) add(cloud.get(), u, v);
    }
  // Holes in step with the stride (every 4th column missing) leave the lattice nearly empty:
  // then every stride^2-th valid pixel instead.
  const size_t per_sample = static_cast<size_t>(config.pixel_stride) * config.pixel_stride;
  if (2 * cloud->size() < valid / per_sample) {
    cloud->clear();
    size_t k = 0;
    for (int v = 0; v < depth.height; ++v)
      for (int u = 0; u < depth.width; ++u)
        if (usable(u, v) && k++ % per_sample == 0) add(cloud.get(), u, v);
  }
  if (cloud->size() < 50)
    throw std::runtime_error("table plane: only " + std::to_string(valid) +
                             " valid depth pixels (nearer than max_depth_m " +
                             std::to_string(config.max_depth_m).substr(0, 5) +
                             " m); cannot estimate the table");
  const Plane plane = tablePlane(cloud, config, workspace);
  TablePlane out;
  out.points = plane.points;
  out.inliers = static_cast<int>(plane.inliers.indices.size());
  if (out.inliers == 0 || out.inliers < config.min_inlier_share * out.points)
    throw std::runtime_error("table plane: no dominant plane in the depth image (" +
                             std::to_string(out.inliers) + " of " + std::to_string(out.points) +
                             " points on the best plane)");
  out.plane_camera = plane.coefficients;
  out.T_table_camera = tableFromPlane(plane.coefficients.head<3>(), plane.coefficients[3]);
  return out;
}

}  // namespace simstack
