#include "simstack/instances/surface_instances.h"

#include <pcl/ModelCoefficients.h>
#include <pcl/point_types.h>
#include <pcl/sample_consensus/method_types.h>
#include <pcl/sample_consensus/model_types.h>
#include <pcl/search/kdtree.h>
#include <pcl/segmentation/extract_clusters.h>
#include <pcl/segmentation/sac_segmentation.h>

#include <Eigen/Dense>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <set>
#include <stdexcept>
#include <string>
#include <utility>

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
  if (!(container_profile_m >= 0.0)) fail("container_profile_m must be >= 0");
  if (!(container_min_arc_deg >= 0.0 && container_min_arc_deg <= 360.0))
    fail("container_min_arc_deg must lie in [0, 360]");
  if (!(container_inside_share >= 0.0 && container_inside_share <= 1.0))
    fail("container_inside_share must lie in [0, 1]");
  if (!(held_container_profile_m >= 0.0)) fail("held_container_profile_m must be >= 0");
  if (!(occluded_plane_m >= 0.0)) fail("occluded_plane_m must be >= 0");
  if (!(held_occluded_plane_m >= 0.0)) fail("held_occluded_plane_m must be >= 0");
  if (!(occluded_margin_m > 0.0)) fail("occluded_margin_m must be > 0");
  if (!(occluded_share > 0.0 && occluded_share <= 1.0)) fail("occluded_share must lie in (0, 1]");
  if (!(occluded_edge_m > 0.0)) fail("occluded_edge_m must be > 0");
  if (!(fit_overlap_share >= 0.0 && fit_overlap_share <= 1.0))
    fail("fit_overlap_share must lie in [0, 1]");
}

namespace {

/// The label of the nearest labelled voxel within `reach` voxels of `p`, -1 none.
int labelNear(const Grid3<int>& labels, const Vec3& p, int reach) {
  const int v = nearestLabelledVoxel(labels, p, reach);
  return v < 0 ? -1 : labels.data[v];
}

/// The points as a PCL cloud, for its searches and segmentations.
pcl::PointCloud<pcl::PointXYZ>::Ptr pointCloud(const Points3& points) {
  pcl::PointCloud<pcl::PointXYZ>::Ptr cloud(new pcl::PointCloud<pcl::PointXYZ>);
  for (const Vec3& p : points) cloud->push_back(pcl::PointXYZ(p.x(), p.y(), p.z()));
  return cloud;
}

/// The `share` quantile of `values` (taken by value: reordered).
double quantile(std::vector<double> values, double share) {
  const size_t k = std::min(values.size() - 1, static_cast<size_t>(share * values.size()));
  std::nth_element(values.begin(), values.begin() + k, values.end());
  return values[k];
}

/// The `share` quantile of the points' heights.
double heightQuantile(const Points3& points, const std::vector<int>& which, double share) {
  std::vector<double> z;
  for (int i : which) z.push_back(points[i].z());
  return quantile(std::move(z), share);
}

}  // namespace

std::vector<std::vector<int>> euclideanClusters(const Points3& points, double tolerance_m,
                                                int min_points) {
  std::vector<std::vector<int>> out;
  if (points.size() < static_cast<size_t>(std::max(1, min_points))) return out;
  const pcl::PointCloud<pcl::PointXYZ>::Ptr cloud = pointCloud(points);
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

RevolutionFit fitCommonRevolution(const Points3& a, const Points3& b, const Vec2& camera_xy,
                                  double bin_m) {
  RevolutionFit fit;
  if (!(bin_m > 0.0)) throw std::invalid_argument("fitCommonRevolution: bin_m must be > 0");
  const auto bin = [&](const Vec3& p) { return static_cast<int>(std::floor(p.z() / bin_m)); };
  std::map<int, std::pair<int, int>> counts;  // height bin -> points of a, of b
  for (const Vec3& p : a) ++counts[bin(p)].first;
  for (const Vec3& p : b) ++counts[bin(p)].second;
  std::map<int, int> column;  // shared height bin -> its radius' unknown
  for (const auto& [k, n] : counts)
    if (n.first >= 3 && n.second >= 3) column.emplace(k, static_cast<int>(column.size()));
  Points3 shared;
  for (const Points3* set : {&a, &b})
    for (const Vec3& p : *set)
      if (column.count(bin(p))) shared.push_back(p);
  fit.points = static_cast<int>(shared.size());
  if (shared.size() < 3 + column.size()) return fit;
  // Centred for conditioning: |p - c|^2 = r^2  <=>  x^2 + y^2 = 2 c . p + (r^2 - |c|^2).
  Vec2 mean = Vec2::Zero();
  for (const Vec3& p : shared) mean += p.head<2>();
  mean /= static_cast<double>(shared.size());
  // Normal equations, accumulated: each point's row is (2 q.x, 2 q.y, one-hot of its bin).
  const int n = 2 + static_cast<int>(column.size());
  Eigen::MatrixXd AtA = Eigen::MatrixXd::Zero(n, n);
  Eigen::VectorXd Aty = Eigen::VectorXd::Zero(n);
  for (const Vec3& p : shared) {
    const Vec2 q = p.head<2>() - mean;
    const int j = 2 + column.at(bin(p));
    const double row[3] = {2 * q.x(), 2 * q.y(), 1.0};
    const int col[3] = {0, 1, j};
    for (int r = 0; r < 3; ++r) {
      for (int t = 0; t < 3; ++t) AtA(col[r], col[t]) += row[r] * row[t];
      Aty(col[r]) += row[r] * q.squaredNorm();
    }
  }
  const Eigen::VectorXd x = AtA.colPivHouseholderQr().solve(Aty);
  if (!x.allFinite()) return fit;
  const Vec2 c(x(0), x(1));
  std::vector<double> radius(column.size());
  for (const auto& [k, j] : column) {
    const double r2 = x(2 + j) + c.squaredNorm();
    if (!(r2 > 0.0)) return fit;
    radius[j] = std::sqrt(r2);
    fit.max_radius_m = std::max(fit.max_radius_m, radius[j]);
  }
  fit.axis = c + mean;
  std::vector<double> residual;
  std::vector<bool> sector(36, false);
  const Vec2 towards_camera = (camera_xy - fit.axis).normalized();
  int inside = 0;
  for (const Vec3& p : shared) {
    const Vec2 d = p.head<2>() - fit.axis;
    const double rho = d.norm();
    residual.push_back(std::abs(rho - radius[column.at(bin(p))]));
    if (rho <= 0.0) continue;
    const double angle = std::atan2(d.y(), d.x());  // -pi..pi
    sector[std::min(35, static_cast<int>((angle + M_PI) / (2 * M_PI) * 36))] = true;
    // A convex object's visible side faces the camera: points beyond the axis are seen from
    // inside.
    if (d.dot(towards_camera) < -0.2 * rho) ++inside;
  }
  std::nth_element(residual.begin(), residual.begin() + residual.size() / 2, residual.end());
  fit.median_residual_m = residual[residual.size() / 2];
  fit.arc_deg = 10.0 * std::count(sector.begin(), sector.end(), true);
  fit.inside_share = static_cast<double>(inside) / static_cast<double>(shared.size());
  fit.valid = true;
  return fit;
}

namespace {

/// Per instance, the points whose nearest labelled voxel is its, at most `max_per_instance` of them
/// evenly spaced in their order.
std::vector<Points3> pointsByInstance(const Points3& points, const InstanceSegmentation& seg,
                                      int max_per_instance) {
  std::vector<Points3> out(seg.size());
  for (const Vec3& p : points) {
    const int v = nearestLabelledVoxel(seg.labels, p);
    if (v >= 0 && seg.labels.data[v] < seg.size()) out[seg.labels.data[v]].push_back(p);
  }
  for (Points3& set : out)
    if (static_cast<int>(set.size()) > max_per_instance) {
      Points3 kept;
      const double step = static_cast<double>(set.size()) / max_per_instance;
      for (int i = 0; i < max_per_instance; ++i) kept.push_back(set[static_cast<size_t>(i * step)]);
      set.swap(kept);
    }
  return out;
}

/// joinInstances, the instances' point sets (pointsByInstance) joined alike.
void joinInstancesAndPoints(InstanceSegmentation* seg, std::vector<Points3>* points, int keep,
                            int drop) {
  joinInstances(seg, keep, drop);
  Points3& kept = (*points)[keep];
  kept.insert(kept.end(), (*points)[drop].begin(), (*points)[drop].end());
  points->erase(points->begin() + drop);
}

/// Whether two instances' points come within `gap_m` of each other on the table (bounding boxes).
bool nearOnTable(const Points3& a, const Points3& b, double gap_m) {
  Vec2 lo_a = Vec2::Constant(1e9), hi_a = -lo_a, lo_b = lo_a, hi_b = hi_a;
  for (const Vec3& p : a) {
    lo_a = lo_a.cwiseMin(p.head<2>());
    hi_a = hi_a.cwiseMax(p.head<2>());
  }
  for (const Vec3& p : b) {
    lo_b = lo_b.cwiseMin(p.head<2>());
    hi_b = hi_b.cwiseMax(p.head<2>());
  }
  return (lo_a.array() <= hi_b.array() + gap_m).all() &&
         (lo_b.array() <= hi_a.array() + gap_m).all();
}

/// An instance's largest planar face: the plane n . p = d (table frame) and its points (the
/// indices of the points given).
struct Face {
  bool valid = false;
  Vec3 normal = Vec3::UnitZ();
  double offset = 0;
  Points3 points;
  std::vector<int> indices;
  Vec3 lo = Vec3::Zero(), hi = Vec3::Zero();  ///< the points' bounding box
  /// A KD-tree over `points`, where the gap test needs one (searched once per pair of faces).
  pcl::search::KdTree<pcl::PointXYZ>::Ptr tree;
};

/// The largest plane through `points` by PCL's RANSAC (inliers within `threshold_m`), a face
/// when it holds at least `min_points` and a third of them.
Face largestFace(const Points3& points, double threshold_m, int min_points) {
  Face face;
  if (static_cast<int>(points.size()) < std::max(3, min_points)) return face;
  const pcl::PointCloud<pcl::PointXYZ>::Ptr cloud = pointCloud(points);
  pcl::SACSegmentation<pcl::PointXYZ> sac;
  sac.setOptimizeCoefficients(true);
  sac.setModelType(pcl::SACMODEL_PLANE);
  sac.setMethodType(pcl::SAC_RANSAC);
  sac.setDistanceThreshold(threshold_m);
  sac.setMaxIterations(200);
  sac.setInputCloud(cloud);
  pcl::PointIndices inliers;
  pcl::ModelCoefficients c;
  sac.segment(inliers, c);
  const int n = static_cast<int>(inliers.indices.size());
  if (c.values.size() != 4 || n < min_points || 3 * n < static_cast<int>(points.size()))
    return face;
  const Vec3 normal(c.values[0], c.values[1], c.values[2]);
  if (!(normal.norm() > 0)) return face;
  face.valid = true;
  face.normal = normal.normalized();
  face.offset = -c.values[3] / normal.norm();
  for (int i : inliers.indices) face.points.push_back(points[i]);
  face.indices = inliers.indices;
  face.lo = face.hi = face.points.front();
  for (const Vec3& p : face.points) {
    face.lo = face.lo.cwiseMin(p);
    face.hi = face.hi.cwiseMax(p);
  }
  return face;
}

/// How well two faces lie on one plane: the smaller of the shares of each face's points that
/// are inliers of the largest plane through both (a plane fitted to both, not one face's
/// plane extrapolated across the gap, where a few degrees of tilt would miss the other).
double commonPlaneShare(const Face& a, const Face& b, double threshold_m) {
  Points3 both = a.points;
  both.insert(both.end(), b.points.begin(), b.points.end());
  const Face common = largestFace(both, threshold_m, 0);
  if (!common.valid) return 0;
  const int na = static_cast<int>(a.points.size());
  int in_a = 0, in_b = 0;
  for (int i : common.indices) (i < na ? in_a : in_b) += 1;
  return std::min(static_cast<double>(in_a) / na, static_cast<double>(in_b) / b.points.size());
}

/// Whether (u, v) lies within `margin` pixels of the camera's image (false for NaN).
bool nearImage(const PinholeCamera& camera, double u, double v, double margin) {
  return u >= -margin && v >= -margin && u <= camera.width + margin && v <= camera.height + margin;
}

/// The camera depth (z, m) of the points per pixel, the nearest where several fall; each point
/// covers the pixels within stride / 2 of its own (3 x 3 at stride 2: the points are every
/// stride-th pixel's, and the blocks close the gaps between them). 0 = none.
std::vector<float> depthOfPoints(const Points3& points_table, const PinholeCamera& camera,
                                 const Transform& T_camera_table, int stride) {
  // Each point's depth at its own pixel (the nearest where several fall), on an image padded by
  // `half` so that points just outside still cover the pixels inside; a minimum filter over
  // the blocks then spreads them. "None" is the largest float until the end.
  const int half = std::max(1, stride) / 2, w = camera.width, h = camera.height;
  constexpr float kNone = std::numeric_limits<float>::max();
  cv::Mat1f centres(h + 2 * half, w + 2 * half, kNone);
  for (const Vec3& p : points_table) {
    const Vec3 c = T_camera_table * p;
    double u = 0, v = 0;
    if (!camera.project(c, &u, &v) || !nearImage(camera, u, v, half + 1)) continue;
    const long x = std::lround(u) + half, y = std::lround(v) + half;
    if (x < 0 || y < 0 || x >= centres.cols || y >= centres.rows) continue;  // no block inside
    float& d = centres(static_cast<int>(y), static_cast<int>(x));
    d = std::min(d, static_cast<float>(c.z()));
  }
  cv::Mat1f spread;
  cv::erode(centres, spread, cv::Mat1b(2 * half + 1, 2 * half + 1, uchar{1}));
  std::vector<float> depth(static_cast<size_t>(w) * h, 0.0f);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const float d = spread(y + half, x + half);
      if (d != kNone) depth[static_cast<size_t>(y) * w + x] = d;
    }
  return depth;
}

/// What lies between two coplanar faces, looked at along the segment joining their nearest
/// points (every 4 mm): the share of it that a surface nearer to the camera than the segment
/// by `margin_m` hides, and the share inside voxels of an instance other than `a` and `b`.
struct Gap {
  double length_m = 0;
  double hidden = 0, other = 0, none = 0;
  /// How far the faces' sides along the gap are apart: along the plane's direction normal to
  /// the gap, the larger difference of the faces' 5th and of their 95th percentiles (m).
  double edge_offset_m = 0;
};

Gap lookIntoGap(const Face& fa, const Face& fb, int a, int b, const Grid3<int>& labels,
                const std::vector<float>& depth, const PinholeCamera& camera,
                const Transform& T_camera_table, double margin_m) {
  // The nearest pair of points: each of a's looked up among b's.
  Vec3 pa = fa.points.front(), pb = fb.points.front();
  double best = std::numeric_limits<double>::infinity();
  pcl::Indices nearest(1);
  std::vector<float> squared(1);
  for (const Vec3& p : fa.points) {
    if (fb.tree->nearestKSearch(pcl::PointXYZ(p.x(), p.y(), p.z()), 1, nearest, squared) < 1)
      continue;
    const double d = (p - fb.points[nearest[0]]).squaredNorm();
    if (d < best) {
      best = d;
      pa = p;
      pb = fb.points[nearest[0]];
    }
  }
  Gap gap;
  gap.length_m = std::sqrt(best);
  const int steps = static_cast<int>(std::ceil(gap.length_m / 0.004));
  int samples = 0, in_view = 0, hidden = 0, other = 0, none = 0;
  for (int i = 1; i < steps; ++i) {
    const Vec3 q = pa + (pb - pa) * (static_cast<double>(i) / steps);
    ++samples;
    if (labels.spec.containsPoint(q)) {
      const Vec3i idx = labels.spec.voxelIndex(q);
      const int l = labels.at(idx.x(), idx.y(), idx.z());
      other += l >= 0 && l != a && l != b;
    }
    const Vec3 c = T_camera_table * q;
    double u = 0, v = 0;
    if (!camera.project(c, &u, &v) || !nearImage(camera, u, v, 1.0)) continue;
    const int x = static_cast<int>(std::lround(u)), y = static_cast<int>(std::lround(v));
    if (x < 0 || y < 0 || x >= camera.width || y >= camera.height) continue;
    ++in_view;  // the shares of hidden and missing depth are of the way the image shows
    const float d = depth[static_cast<size_t>(y) * camera.width + x];
    hidden += d > 0.0f && d < c.z() - margin_m;
    none += d == 0.0f;
  }
  // One face cut by a nearer object: its two pieces' sides along the gap line up (a box top's
  // front and back edges); two objects' faces of one height seldom do.
  const Vec3 along = (pb - pa) - fa.normal * fa.normal.dot(pb - pa);
  if (along.norm() > 1e-9) {
    const Vec3 across = fa.normal.cross(along.normalized());
    std::vector<double> wa, wb;
    for (const Vec3& p : fa.points) wa.push_back(across.dot(p));
    for (const Vec3& p : fb.points) wb.push_back(across.dot(p));
    gap.edge_offset_m = std::max(std::abs(quantile(wa, 0.05) - quantile(wb, 0.05)),
                                 std::abs(quantile(wa, 0.95) - quantile(wb, 0.95)));
  }
  if (samples > 0) gap.other = static_cast<double>(other) / samples;
  gap.none = 1.0;  // nothing of the way in view: no evidence that anything hides it
  if (in_view > 0) {
    gap.hidden = static_cast<double>(hidden) / in_view;
    gap.none = static_cast<double>(none) / in_view;
  }
  return gap;
}

}  // namespace

void joinInstances(InstanceSegmentation* seg, int keep, int drop) {
  if (keep < 0 || drop <= keep || drop >= seg->size())
    throw std::invalid_argument("joinInstances: instance " + std::to_string(drop) +
                                " cannot join " + std::to_string(keep) + " of " +
                                std::to_string(seg->size()));
  const int nk = seg->voxel_counts[keep], nd = seg->voxel_counts[drop];
  if (nk + nd > 0)
    seg->centres_table[keep] =
        (seg->centres_table[keep] * nk + seg->centres_table[drop] * nd) / double(nk + nd);
  seg->voxel_counts[keep] = nk + nd;
  for (int& l : seg->labels.data) {
    if (l == drop) l = keep;
    if (l > drop) --l;
  }
  seg->centres_table.erase(seg->centres_table.begin() + drop);
  seg->voxel_counts.erase(seg->voxel_counts.begin() + drop);
}

namespace {

/// Per instance, the object of `held` holding more than half of its points (`points`, one set
/// per instance; a point is an object's when one of the object's lies within `reach_m`), -1 for
/// none.
std::vector<int> heldObjects(const std::vector<Points3>& points, const std::vector<Points3>& held,
                             double reach_m) {
  Points3 all;
  std::vector<int> owner;
  for (size_t k = 0; k < held.size(); ++k)
    for (const Vec3& p : held[k]) {
      all.push_back(p);
      owner.push_back(static_cast<int>(k));
    }
  std::vector<int> out(points.size(), -1);
  if (all.empty()) return out;
  pcl::search::KdTree<pcl::PointXYZ> tree;
  tree.setInputCloud(pointCloud(all));
  pcl::Indices nearest(1);
  std::vector<float> squared(1);
  for (size_t k = 0; k < points.size(); ++k) {
    std::map<int, int> votes;
    for (const Vec3& p : points[k])
      if (tree.nearestKSearch(pcl::PointXYZ(p.x(), p.y(), p.z()), 1, nearest, squared) == 1 &&
          squared[0] <= reach_m * reach_m)
        ++votes[owner[nearest[0]]];
    for (const auto& [object, n] : votes)
      if (2 * n > static_cast<int>(points[k].size())) out[k] = object;
  }
  return out;
}

/// Which instances an earlier perception held as one object (heldObjects, within 1 cm; every
/// pair is together without `held`), kept in step with the joins.
class HeldGroups {
 public:
  HeldGroups(const std::vector<Points3>& points, const std::vector<Points3>* held)
      : held_(held != nullptr),
        group_(held ? heldObjects(points, *held, 0.01) : std::vector<int>()) {}
  bool together(int a, int b) const { return !held_ || (group_[a] >= 0 && group_[a] == group_[b]); }
  /// Some pair is together.
  bool any() const {
    if (!held_) return true;
    std::vector<int> objects;
    for (int g : group_)
      if (g >= 0) objects.push_back(g);
    std::sort(objects.begin(), objects.end());
    return std::adjacent_find(objects.begin(), objects.end()) != objects.end();
  }
  void joined(int drop) {
    if (held_) group_.erase(group_.begin() + drop);
  }

 private:
  bool held_;
  std::vector<int> group_;
};

/// joinOpenContainers' loop within `profile_m`; with `held`, only for pairs of one held object
/// (HeldGroups).
int joinContainers(const Points3& points_table, const Vec3& camera_table, double profile_m,
                   const std::vector<Points3>* held, const SurfaceInstanceConfig& config,
                   InstanceSegmentation* seg) {
  constexpr int kMaxPoints = 1500;     // per instance: the fit's cost stays small
  constexpr double kMaxRadiusM = 0.3;  // larger "containers" are rows of objects
  constexpr double kMaxGapM = 0.1;     // between the bounding boxes of a pot's two walls
  std::vector<Points3> points = pointsByInstance(points_table, *seg, kMaxPoints);
  HeldGroups groups(points, held);
  if (!groups.any()) return 0;
  int joins = 0;
  for (;;) {
    int best_a = -1, best_b = -1;
    double best = profile_m;
    for (int a = 0; a < seg->size(); ++a)
      for (int b = a + 1; b < seg->size(); ++b) {
        if (!groups.together(a, b) ||
            static_cast<int>(std::min(points[a].size(), points[b].size())) < config.min_points ||
            !nearOnTable(points[a], points[b], kMaxGapM))
          continue;
        const RevolutionFit f = fitCommonRevolution(points[a], points[b], camera_table.head<2>());
        if (f.valid && f.median_residual_m <= best && f.arc_deg >= config.container_min_arc_deg &&
            f.inside_share >= config.container_inside_share && f.max_radius_m <= kMaxRadiusM) {
          best = f.median_residual_m;
          best_a = a;
          best_b = b;
        }
      }
    if (best_a < 0) return joins;
    joinInstancesAndPoints(seg, &points, best_a, best_b);
    groups.joined(best_b);
    ++joins;
  }
}

}  // namespace

int joinOpenContainers(const Points3& points_table, const Vec3& camera_table,
                       const SurfaceInstanceConfig& config, InstanceSegmentation* seg) {
  config.validate();
  if (!config.enabled || config.container_profile_m <= 0.0) return 0;
  return joinContainers(points_table, camera_table, config.container_profile_m, nullptr, config,
                        seg);
}

int joinHeldContainers(const Points3& points_table, const Vec3& camera_table,
                       const std::vector<Points3>& held, const SurfaceInstanceConfig& config,
                       InstanceSegmentation* seg) {
  config.validate();
  if (!config.enabled || config.held_container_profile_m <= 0.0 || held.empty() || seg->size() < 2)
    return 0;
  return joinContainers(points_table, camera_table, config.held_container_profile_m, &held, config,
                        seg);
}

namespace {

/// joinOccludedPieces' loop with faces found within `plane_m`; with `held`, only for pairs of
/// one held object (HeldGroups), and a third instance between them does not part them: the
/// earlier perception saw the object whole around it.
int joinOccluded(const Points3& points_table, const PinholeCamera& camera,
                 const Transform& T_table_camera, int stride, double plane_m,
                 const std::vector<Points3>* held, const SurfaceInstanceConfig& config,
                 InstanceSegmentation* seg) {
  constexpr int kMaxPoints = 1500;         // per instance: RANSAC's cost stays small
  constexpr double kMinGapM = 0.01;        // nearer faces touch: nothing hides a gap between them
  constexpr double kMaxGapM = 0.3;         // a face hidden over more is not one object's
  constexpr double kMaxAngleDeg = 20.0;    // between the faces' normals
  constexpr double kMaxOtherShare = 0.6;   // of the gap inside a third instance: it stands between
  constexpr double kMaxHoleShare = 0.4;    // of the gap with no depth: the camera's shadow beside
                                           // the hiding surface; more is the table seen through
  constexpr double kMinCommonShare = 0.7;  // of each face's points on the plane through both
  std::vector<Points3> points = pointsByInstance(points_table, *seg, kMaxPoints);
  HeldGroups groups(points, held);
  if (!groups.any()) return 0;  // no two instances of one held object: nothing to look at
  const Transform T_camera_table = T_table_camera.inverse();
  const std::vector<float> depth = depthOfPoints(points_table, camera, T_camera_table, stride);
  const auto faceOf = [&](const Points3& p) {
    Face face = largestFace(p, plane_m, config.min_points);
    if (face.valid) {
      face.tree.reset(new pcl::search::KdTree<pcl::PointXYZ>);
      face.tree->setInputCloud(pointCloud(face.points));
    }
    return face;
  };
  std::vector<Face> faces;
  for (const Points3& p : points) faces.push_back(faceOf(p));
  const double min_cos = std::cos(kMaxAngleDeg * M_PI / 180.0);
  int joins = 0;
  for (;;) {
    int best_a = -1, best_b = -1;
    double best = kMinCommonShare;
    for (int a = 0; a < seg->size(); ++a)
      for (int b = a + 1; b < seg->size(); ++b) {
        const Face& fa = faces[a];
        const Face& fb = faces[b];
        if (!groups.together(a, b)) continue;
        if (!fa.valid || !fb.valid || std::abs(fa.normal.dot(fb.normal)) < min_cos) continue;
        // The boxes' distance bounds the nearest points' from below: far apart, no gap test.
        if ((fb.lo - fa.hi).cwiseMax(fa.lo - fb.hi).cwiseMax(0.0).norm() > kMaxGapM) continue;
        const Gap gap = lookIntoGap(fa, fb, a, b, seg->labels, depth, camera, T_camera_table,
                                    config.occluded_margin_m);
        // Hidden: `occluded_share` of the way where there is depth.
        if (gap.length_m < kMinGapM || gap.length_m > kMaxGapM || gap.none > kMaxHoleShare ||
            gap.hidden < config.occluded_share * (1.0 - gap.none) ||
            (!held && gap.other > kMaxOtherShare) || gap.edge_offset_m > config.occluded_edge_m)
          continue;
        const double common = commonPlaneShare(fa, fb, plane_m);
        if (common < best) continue;
        best = common;
        best_a = a;
        best_b = b;
      }
    if (best_a < 0) return joins;
    joinInstancesAndPoints(seg, &points, best_a, best_b);
    faces.erase(faces.begin() + best_b);
    faces[best_a] = faceOf(points[best_a]);
    groups.joined(best_b);
    ++joins;
  }
}

}  // namespace

int joinOccludedPieces(const Points3& points_table, const PinholeCamera& camera,
                       const Transform& T_table_camera, int stride,
                       const SurfaceInstanceConfig& config, InstanceSegmentation* seg) {
  config.validate();
  if (!config.enabled || config.occluded_plane_m <= 0.0 || seg->size() < 2 || camera.width <= 0 ||
      camera.height <= 0)
    return 0;
  return joinOccluded(points_table, camera, T_table_camera, stride, config.occluded_plane_m,
                      nullptr, config, seg);
}

int joinHeldOccludedPieces(const Points3& points_table, const PinholeCamera& camera,
                           const Transform& T_table_camera, int stride,
                           const std::vector<Points3>& held, const SurfaceInstanceConfig& config,
                           InstanceSegmentation* seg) {
  config.validate();
  if (!config.enabled || config.held_occluded_plane_m <= 0.0 || held.empty() || seg->size() < 2 ||
      camera.width <= 0 || camera.height <= 0)
    return 0;
  return joinOccluded(points_table, camera, T_table_camera, stride, config.held_occluded_plane_m,
                      &held, config, seg);
}

}  // namespace simstack
