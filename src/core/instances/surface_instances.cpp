#include "simstack/instances/surface_instances.h"

#include <pcl/point_types.h>
#include <pcl/search/kdtree.h>
#include <pcl/segmentation/extract_clusters.h>

#include <algorithm>
#include <map>
#include <set>
#include <stdexcept>
#include <string>

#include "simstack/instances/surface_segments.h"

namespace simstack {

void SurfaceInstanceConfig::validate() const {
  auto fail = [](const std::string& what) {
    throw std::invalid_argument("surface_instances." + what);
  };
  if (!(min_height_m >= 0.0)) fail("min_height_m must be >= 0");
  if (!(cluster_tolerance_m > 0.0)) fail("cluster_tolerance_m must be > 0");
  if (min_points < 1) fail("min_points must be >= 1");
  if (!(max_base_height_m >= min_height_m)) fail("max_base_height_m must be >= min_height_m");
  if (!(attach_share > 0.0 && attach_share <= 1.0)) fail("attach_share must lie in (0, 1]");
}

namespace {

/// The label of the nearest labelled voxel within `reach` voxels of `p`, -1 none.
int labelNear(const Grid3<int>& labels, const Vec3& p, int reach) {
  const int v = nearestLabelledVoxel(labels, p, reach);
  return v < 0 ? -1 : labels.data[v];
}

/// The `share` quantile of the points' heights.
double heightQuantile(const Points3& points, const std::vector<int>& which, double share) {
  std::vector<double> z;
  for (int i : which) z.push_back(points[i].z());
  const size_t k = std::min(z.size() - 1, static_cast<size_t>(share * z.size()));
  std::nth_element(z.begin(), z.begin() + k, z.end());
  return z[k];
}

}  // namespace

std::vector<std::vector<int>> euclideanClusters(const Points3& points, double tolerance_m,
                                                int min_points) {
  std::vector<std::vector<int>> out;
  if (points.size() < static_cast<size_t>(std::max(1, min_points))) return out;
  pcl::PointCloud<pcl::PointXYZ>::Ptr cloud(new pcl::PointCloud<pcl::PointXYZ>);
  for (const Vec3& p : points) cloud->push_back(pcl::PointXYZ(p.x(), p.y(), p.z()));
  pcl::search::KdTree<pcl::PointXYZ>::Ptr tree(new pcl::search::KdTree<pcl::PointXYZ>);
  tree->setInputCloud(cloud);
  pcl::EuclideanClusterExtraction<pcl::PointXYZ> ec;
  ec.setClusterTolerance(tolerance_m);
  ec.setMinClusterSize(std::max(1, min_points));
  ec.setMaxClusterSize(static_cast<int>(cloud->size()));
  ec.setSearchMethod(tree);
  ec.setInputCloud(cloud);
  std::vector<pcl::PointIndices> found;
  ec.extract(found);
  for (const auto& idx : found) out.emplace_back(idx.indices.begin(), idx.indices.end());
  return out;
}

int addSurfaceInstances(const Points3& points_table, const SurfaceInstanceConfig& config,
                        InstanceSegmentation* seg, const std::vector<int>* patch) {
  config.validate();
  if (!config.enabled) return 0;
  Grid3<int>& labels = seg->labels;
  const GridSpec& g = labels.spec;
  if (patch && patch->size() != points_table.size())
    throw std::invalid_argument("addSurfaceInstances: " + std::to_string(patch->size()) +
                                " patch labels for " + std::to_string(points_table.size()) +
                                " points");
  std::vector<int> unexplained;
  std::map<int, std::map<int, int>> patch_instances;  // patch -> instance -> explained points
  for (size_t i = 0; i < points_table.size(); ++i) {
    const Vec3i c = g.voxelIndex(points_table[i]);
    if (!g.inside(c.x(), c.y(), c.z())) continue;
    const int v = nearestLabelledVoxel(labels, points_table[i]);
    if (v < 0)
      unexplained.push_back(static_cast<int>(i));
    else if (patch && (*patch)[i] >= 0)
      ++patch_instances[(*patch)[i]][labels.data[v]];
  }
  // The instance a point lies against: the one holding most of its patch's explained points,
  // else (no patch, or one no instance explains) one within two voxels.
  std::map<int, int> patch_owner;
  for (const auto& [p, counts] : patch_instances)
    patch_owner[p] =
        std::max_element(counts.begin(), counts.end(), [](const auto& a, const auto& b) {
          return a.second < b.second;
        })->first;
  const auto against = [&](int i) {
    if (patch && (*patch)[i] >= 0) {
      const auto it = patch_owner.find((*patch)[i]);
      if (it != patch_owner.end()) return it->second;
    }
    return labelNear(labels, points_table[i], 2);
  };
  int added = 0;
  Points3 loose;
  for (int i : unexplained) loose.push_back(points_table[i]);
  for (std::vector<int> cluster :
       euclideanClusters(loose, config.cluster_tolerance_m, config.min_points)) {
    for (int& i : cluster) i = unexplained[i];
    if (heightQuantile(points_table, cluster, 0.9) < config.min_height_m) continue;
    std::map<int, int> near;
    for (int i : cluster)
      if (const int l = against(i); l >= 0) ++near[l];
    int label = seg->size(), most = 0;  // a new instance, unless it lies against one
    for (const auto& [l, n] : near)
      if (n >= config.attach_share * cluster.size() && n > most) {
        label = l;
        most = n;
      }
    // A surface that does not reach down to the table stands on nothing seen: a part of the
    // nearest instance (a bowl's front wall the network placed behind it), else left out.
    if (label == seg->size() &&
        heightQuantile(points_table, cluster, 0.1) > config.max_base_height_m) {
      std::map<int, int> nearest;
      for (int i : cluster)
        if (const int l = labelNear(labels, points_table[i], 4); l >= 0) ++nearest[l];
      if (nearest.empty()) continue;
      label = std::max_element(nearest.begin(), nearest.end(), [](const auto& a, const auto& b) {
                return a.second < b.second;
              })->first;
    }
    // Its voxels, and those below them down to the table: it stands there.
    std::set<int> voxels;
    for (int i : cluster) {
      const Vec3i c = g.voxelIndex(points_table[i]);
      for (int z = c.z(); z >= 0; --z) {
        if (labels.at(c.x(), c.y(), z) >= 0) break;
        voxels.insert(g.linear(c.x(), c.y(), z));
      }
    }
    if (voxels.empty()) continue;
    if (label == seg->size()) {
      seg->centres_table.push_back(Vec3::Zero());
      seg->voxel_counts.push_back(0);
      ++added;
    }
    Vec3 sum = seg->centres_table[label] * seg->voxel_counts[label];
    for (int v : voxels) {
      labels.data[v] = label;
      const Vec3i c = g.unravel(v);
      sum += g.voxelCentre(c.x(), c.y(), c.z());
    }
    seg->voxel_counts[label] += static_cast<int>(voxels.size());
    seg->centres_table[label] = sum / seg->voxel_counts[label];
  }
  return added;
}

}  // namespace simstack
