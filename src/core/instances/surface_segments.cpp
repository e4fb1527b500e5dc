#include "simstack/instances/surface_segments.h"

#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/segmentation/lccp_segmentation.h>
#include <pcl/segmentation/supervoxel_clustering.h>
#include <Eigen/Eigenvalues>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <deque>
#include <limits>
#include <map>
#include <numeric>
#include <optional>
#include <random>
#include <set>
#include <stdexcept>
#include <string>
#include <utility>

namespace simstack {

void SurfaceSegmentConfig::validate() const {
  auto fail = [](const std::string& what) { throw std::invalid_argument("segments." + what); };
  if (pixel_stride < 1) fail("pixel_stride must be >= 1");
  if (!(voxel_resolution_m > 0.0)) fail("voxel_resolution_m must be > 0");
  if (!(seed_resolution_m > voxel_resolution_m))
    fail("seed_resolution_m must be larger than voxel_resolution_m");
  if (!(concavity_tolerance_deg >= 0.0 && concavity_tolerance_deg < 90.0))
    fail("concavity_tolerance_deg must lie in [0, 90)");
  if (min_segment_points < 1) fail("min_segment_points must be >= 1");
  if (!(min_instance_share > 0.0 && min_instance_share <= 0.5))
    fail("min_instance_share must lie in (0, 0.5]");
  if (!(free_space_margin_m >= 0.0)) fail("free_space_margin_m must be >= 0");
  if (!(max_free_share >= 0.0 && max_free_share < 1.0)) fail("max_free_share must lie in [0, 1)");
  if (hull_samples < 1) fail("hull_samples must be >= 1");
  if (!(fragment_share > 0.0 && fragment_share <= 1.0)) fail("fragment_share must lie in (0, 1]");
  if (max_unseen_points < 0) fail("max_unseen_points must be >= 0");
  if (!(apart_vote_divergence >= -1.0 && apart_vote_divergence <= 1.0))
    fail("apart_vote_divergence must lie in [-1, 1]");
  if (min_boundary_faces < 1) fail("min_boundary_faces must be >= 1");
  if (!(same_centre_m >= 0.0)) fail("same_centre_m must be >= 0");
  if (!(depth_jump_ratio >= 0.0)) fail("depth_jump_ratio must be >= 0");
  if (!(depth_jump_share > 0.0 && depth_jump_share <= 1.0))
    fail("depth_jump_share must lie in (0, 1]");
  if (!(crease_angle_deg >= 0.0 && crease_angle_deg < 90.0))
    fail("crease_angle_deg must lie in [0, 90)");
  if (crease_window_px < 3 || crease_window_px % 2 == 0)
    fail("crease_window_px must be odd and >= 3");
  if (crease_offset_px < 2) fail("crease_offset_px must be >= 2");
}

Image<uint8_t> concaveCreases(const DepthImage& depth, const PinholeCamera& camera,
                              const SurfaceSegmentConfig& config) {
  config.validate();
  const int w = depth.width, h = depth.height;
  Image<uint8_t> out(w, h, 0);
  if (config.crease_angle_deg <= 0.0 || w == 0 || h == 0) return out;
  // Sums of the valid camera-frame points and their count over each window (OpenCV's box
  // filter; beyond the image counts as missing).
  cv::Mat points(h, w, CV_64FC3, cv::Scalar::all(0.0)), valid(h, w, CV_64F, cv::Scalar(0.0));
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u) {
      const float d = depth.at(u, v);
      if (!validDepth(d)) continue;
      const Vec3 p = camera.backproject(u, v, d);
      points.at<cv::Vec3d>(v, u) = cv::Vec3d(p.x(), p.y(), p.z());
      valid.at<double>(v, u) = 1.0;
    }
  const int side = config.crease_window_px;
  cv::Mat sums, counts;
  cv::boxFilter(points, sums, -1, cv::Size(side, side), cv::Point(-1, -1), false,
                cv::BORDER_CONSTANT);
  cv::boxFilter(valid, counts, -1, cv::Size(side, side), cv::Point(-1, -1), false,
                cv::BORDER_CONSTANT);
  // The averaged surface where at least half of a full window is measured (and, with depth
  // steps, where it stays on the pixel's own surface).
  const double ratio = config.depth_jump_ratio;
  std::vector<Vec3> mean(static_cast<size_t>(w) * h, Vec3::Zero());
  std::vector<char> has_mean(mean.size(), 0);
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u) {
      const double n = counts.at<double>(v, u);
      if (!validDepth(depth.at(u, v)) || 2.0 * n < side * side) continue;
      const cv::Vec3d sum = sums.at<cv::Vec3d>(v, u);
      const Vec3 m = Vec3(sum[0], sum[1], sum[2]) / n;
      // A window across a depth step averages two surfaces into a slope that is on neither.
      if (ratio > 0.0 && std::fabs(m.z() - depth.at(u, v)) > ratio * depth.at(u, v)) continue;
      mean[v * w + u] = m;
      has_mean[v * w + u] = 1;
    }
  // Normals of the averaged surface, turned towards the camera.
  std::vector<Vec3> normal(mean.size(), Vec3::Zero());
  std::vector<char> has_normal(mean.size(), 0);
  for (int v = 1; v + 1 < h; ++v)
    for (int u = 1; u + 1 < w; ++u) {
      const int i = v * w + u;
      if (!has_mean[i] || !has_mean[i - 1] || !has_mean[i + 1] || !has_mean[i - w] ||
          !has_mean[i + w])
        continue;
      Vec3 n = (mean[i + 1] - mean[i - 1]).cross(mean[i + w] - mean[i - w]);
      const double norm = n.norm();
      if (!(norm > 0.0)) continue;
      n /= norm;
      normal[i] = n.dot(mean[i]) > 0.0 ? -n : n;
      has_normal[i] = 1;
    }
  const double cos_angle = std::cos(config.crease_angle_deg * M_PI / 180.0);
  const int k = config.crease_offset_px;
  const std::pair<int, int> steps[4] = {{k, 0}, {0, k}, {k, k}, {k, -k}};
  for (int v = 0; v < h; ++v)
    for (int u = 0; u < w; ++u) {
      const int a = v * w + u;
      if (!has_normal[a]) continue;
      for (const auto& [du, dv] : steps) {
        const int bu = u + du, bv = v + dv;
        if (bu < 0 || bv < 0 || bu >= w || bv >= h || !has_normal[bv * w + bu]) continue;
        const int b = bv * w + bu;
        // A valley: the normals differ, and along the way from one to the other they turn
        // towards each other (on a ridge they turn apart).
        if (normal[a].dot(normal[b]) < cos_angle &&
            (normal[a] - normal[b]).dot(mean[a] - mean[b]) < 0.0)
          out.at(u + du / 2, v + dv / 2) = 1;
      }
    }
  return out;
}

namespace {
bool insideBox(const GridSpec& grid, const Vec3& p) {
  const Vec3 q = (p - grid.origin_table) / grid.extent_m();
  return (q.array() >= 0.0).all() && (q.array() <= 1.0).all();
}

/// The points of a segmented view by pixel, for walking the image at the stride; `camera_points`
/// are the same points in the camera frame (z: depth along the optical axis).
class ImageNeighbours {
 public:
  /// `creases`: concaveCreases of the view (empty: none).
  ImageNeighbours(const SurfaceSegments& s, const pcl::PointCloud<pcl::PointXYZ>& camera_points,
                  const SurfaceSegmentConfig& c, const Image<uint8_t>& creases)
      : s_(s),
        points_(camera_points),
        ratio_(c.depth_jump_ratio),
        stride_(c.pixel_stride),
        point_at_(static_cast<size_t>(s.depth.width) * s.depth.height, -1),
        on_crease_(s.pixel.size(), 0),
        creases_(!creases.empty()) {
    for (size_t i = 0; i < s.pixel.size(); ++i) {
      point_at_[s.pixel[i]] = static_cast<int>(i);
      if (creases_) on_crease_[i] = creases.pixels[s.pixel[i]];
    }
  }
  /// Calls f(j) for the points one stride right of and below point i (`both_ways`: left of and
  /// above it too).
  template <class F>
  void forNeighbours(int i, bool both_ways, F&& f) const {
    const int w = s_.depth.width, u = s_.pixel[i] % w, v = s_.pixel[i] / w;
    const std::pair<int, int> next[4] = {
        {u + stride_, v}, {u, v + stride_}, {u - stride_, v}, {u, v - stride_}};
    for (int k = 0; k < (both_ways ? 4 : 2); ++k) {
      const auto [nu, nv] = next[k];
      if (nu < 0 || nv < 0 || nu >= w || nv >= s_.depth.height) continue;
      const int j = point_at_[nv * w + nu];
      if (j >= 0) f(j);
    }
  }
  /// Whether points i and j lie on two surfaces, one seen past the other's edge.
  bool stepped(int i, int j) const {
    const float a = points_[i].z, b = points_[j].z;
    return ratio_ > 0.0 && std::fabs(a - b) > ratio_ * std::min(a, b);
  }
  bool onCrease(int i) const { return on_crease_[i] != 0; }
  bool creases() const { return creases_; }

 private:
  const SurfaceSegments& s_;
  const pcl::PointCloud<pcl::PointXYZ>& points_;
  double ratio_;
  int stride_;
  std::vector<int> point_at_;
  std::vector<char> on_crease_;
  bool creases_;
};

/// Label pairs whose points neighbour in the image mostly across a depth step
/// (`depth_jump_share` of the pairs): `label` per point, `skip` = none.
template <class Label>
std::set<std::pair<Label, Label>> steppedPairs(const ImageNeighbours& image,
                                               const std::vector<Label>& label, Label skip,
                                               double share) {
  std::map<std::pair<Label, Label>, std::pair<int, int>> pairs;  // (neighbours, steps)
  for (size_t i = 0; i < label.size(); ++i) {
    if (label[i] == skip) continue;
    image.forNeighbours(static_cast<int>(i), false, [&](int j) {
      if (label[j] == skip || label[j] == label[i]) return;
      auto& [neighbours, steps] = pairs[std::minmax(label[i], label[j])];
      ++neighbours;
      steps += image.stepped(static_cast<int>(i), j);
    });
  }
  std::set<std::pair<Label, Label>> out;
  for (const auto& [key, count] : pairs)
    if (count.second >= share * count.first) out.insert(key);
  return out;
}

/// Supervoxel adjacency without the pairs across depth steps: their surfaces take no part in
/// each other's convexity.
void cutSteppedAdjacency(const ImageNeighbours& image,
                         const pcl::PointCloud<pcl::PointXYZL>& labelled, double share,
                         std::multimap<std::uint32_t, std::uint32_t>* adjacency) {
  std::vector<std::uint32_t> voxel_of(labelled.size());
  for (size_t i = 0; i < voxel_of.size(); ++i) voxel_of[i] = labelled.points[i].label;
  const auto stepped = steppedPairs<std::uint32_t>(image, voxel_of, 0u, share);
  for (auto it = adjacency->begin(); it != adjacency->end();)
    it = stepped.count(std::minmax(it->first, it->second)) ? adjacency->erase(it) : std::next(it);
}

/// Cuts each patch into the parts its points form through neighbours in the image with no depth
/// step between them: a supervoxel can straddle two objects where one hides the other. With
/// creases, a part grows no further across a crease point; the creases are then shared out
/// among the parts, and the parts of one patch meet at a concave edge (added to `concave`). The
/// largest part keeps the patch's number; other parts of at least `min_points` become new patches,
/// smaller ones leave every patch.
void splitPatches(const ImageNeighbours& image, int min_points, SurfaceSegments* s,
                  std::set<std::pair<int, int>>* concave) {
  const int n = static_cast<int>(s->patch.size());
  std::vector<int> part(n, -1);
  std::vector<std::vector<int>> parts;
  for (int seed = 0; seed < n; ++seed) {
    if (s->patch[seed] < 0 || part[seed] >= 0 || image.onCrease(seed)) continue;
    std::vector<int> members{seed};
    part[seed] = static_cast<int>(parts.size());
    for (size_t k = 0; k < members.size(); ++k) {
      const int i = members[k];
      if (image.onCrease(i)) continue;  // reached, but the part grows no further across it
      image.forNeighbours(i, true, [&](int j) {
        if (part[j] >= 0 || s->patch[j] != s->patch[seed] || image.stepped(i, j)) return;
        part[j] = part[seed];
        members.push_back(j);
      });
    }
    parts.push_back(std::move(members));
  }
  if (image.creases()) {
    // The rest of each crease goes to the nearest part of its patch, all parts growing at once:
    // parts cut by a crease meet in its middle, where the depth steps between them are judged.
    std::deque<int> front;
    for (int i = 0; i < n; ++i)
      if (part[i] >= 0) front.push_back(i);
    while (!front.empty()) {
      const int i = front.front();
      front.pop_front();
      image.forNeighbours(i, true, [&](int j) {
        if (part[j] >= 0 || s->patch[j] != s->patch[i] || image.stepped(i, j)) return;
        part[j] = part[i];
        parts[part[i]].push_back(j);
        front.push_back(j);
      });
    }
  }
  for (int i = 0; i < n; ++i)
    if (part[i] < 0) s->patch[i] = -1;  // crease points no part reached
  std::vector<int> largest(s->patches, -1);
  for (size_t p = 0; p < parts.size(); ++p) {
    int& best = largest[s->patch[parts[p].front()]];
    if (best < 0 || parts[p].size() > parts[best].size()) best = static_cast<int>(p);
  }
  std::map<int, std::vector<int>> pieces;  // per patch: the patches its parts became
  for (size_t p = 0; p < parts.size(); ++p) {
    const int from = s->patch[parts[p].front()];
    if (largest[from] == static_cast<int>(p)) {
      pieces[from].push_back(from);
      continue;
    }
    const int to = parts[p].size() >= static_cast<size_t>(min_points) ? s->patches++ : -1;
    for (int i : parts[p]) s->patch[i] = to;
    if (to >= 0) pieces[from].push_back(to);
  }
  if (!image.creases()) return;
  for (const auto& [from, list] : pieces)
    for (size_t a = 0; a < list.size(); ++a)
      for (size_t b = a + 1; b < list.size(); ++b) concave->insert(std::minmax(list[a], list[b]));
}

}  // namespace

std::map<std::uint32_t, std::uint32_t> mergeSmallSegments(
    const std::map<std::uint32_t, std::uint32_t>& lccp_segment_of,
    const std::multimap<std::uint32_t, std::uint32_t>& adjacency, size_t max_small,
    std::map<std::uint32_t, std::set<std::uint32_t>>* neighbours) {
  std::map<std::uint32_t, std::uint32_t> name_of_lccp;  // LCCP's label -> lowest member
  for (const auto& [voxel, segment] : lccp_segment_of) name_of_lccp.try_emplace(segment, voxel);
  std::map<std::uint32_t, std::uint32_t> owner;
  std::map<std::uint32_t, std::vector<std::uint32_t>> members;
  for (const auto& [voxel, segment] : lccp_segment_of) {
    owner[voxel] = name_of_lccp.at(segment);
    members[owner[voxel]].push_back(voxel);
  }
  auto& near = *neighbours;
  near.clear();
  for (const auto& [a, b] : adjacency) {
    const auto ia = owner.find(a), ib = owner.find(b);
    if (ia == owner.end() || ib == owner.end() || ia->second == ib->second) continue;
    near[ia->second].insert(ib->second);
    near[ib->second].insert(ia->second);
  }
  for (bool merged = true; merged;) {
    merged = false;
    for (auto it = members.begin(); it != members.end();) {
      const std::uint32_t small = it->first;
      const auto around = near.find(small);
      if (it->second.size() > max_small || around == near.end() || around->second.empty()) {
        ++it;
        continue;
      }
      // The largest neighbour, if it is at least as large as the segment (as in PCL).
      std::uint32_t into = small;
      size_t into_size = it->second.size();
      for (std::uint32_t n : around->second) {
        const size_t size = members.at(n).size();
        if (into == small ? size >= into_size : size > into_size) {
          into = n;
          into_size = size;
        }
      }
      if (into == small) {
        ++it;
        continue;
      }
      for (std::uint32_t voxel : it->second) owner[voxel] = into;
      auto& target = members.at(into);
      target.insert(target.end(), it->second.begin(), it->second.end());
      for (std::uint32_t n : around->second) {
        near[n].erase(small);
        if (n == into) continue;
        near[n].insert(into);
        near[into].insert(n);
      }
      near.erase(around);
      it = members.erase(it);
      merged = true;
    }
  }
  for (auto it = near.begin(); it != near.end();)
    it = it->second.empty() ? near.erase(it) : std::next(it);
  return owner;
}

SurfaceSegments segmentVisibleSurface(const DepthImage& depth, const PinholeCamera& camera,
                                      const Transform& T_table_camera, double min_height_m,
                                      const SurfaceSegmentConfig& config, const GridSpec* grid) {
  config.validate();
  if (depth.width != camera.width || depth.height != camera.height)
    throw std::invalid_argument("segmentVisibleSurface: the depth image is " +
                                std::to_string(depth.width) + "x" + std::to_string(depth.height) +
                                " but the camera " + std::to_string(camera.width) + "x" +
                                std::to_string(camera.height));
  SurfaceSegments out;
  out.depth = depth;
  out.camera = camera;
  out.T_table_camera = T_table_camera;
  auto cloud = std::make_shared<pcl::PointCloud<pcl::PointXYZ>>();
  const LatticeStart start = latticeStart(depth, config.pixel_stride);
  for (int v = start.v; v < depth.height; v += config.pixel_stride)
    for (int u = start.u; u < depth.width; u += config.pixel_stride) {
      const float d = depth.at(u, v);
      if (!validDepth(d)) continue;
      const Vec3 q = camera.backproject(u, v, d);
      const Vec3 p = T_table_camera * q;
      if (!(p.z() >= min_height_m)) continue;
      if (grid && !insideBox(*grid, p)) continue;
      out.points_table.push_back(p);
      out.pixel.push_back(v * depth.width + u);
      // Camera frame: the supervoxels turn their normals towards the origin, which must be
      // the viewpoint for LCCP's convexity test to read edges the right way round.
      cloud->push_back(pcl::PointXYZ(static_cast<float>(q.x()), static_cast<float>(q.y()),
                                     static_cast<float>(q.z())));
    }
  out.patch.assign(out.points_table.size(), -1);
  if (cloud->size() < static_cast<size_t>(config.min_segment_points)) return out;

  pcl::SupervoxelClustering<pcl::PointXYZ> supervoxels(
      static_cast<float>(config.voxel_resolution_m), static_cast<float>(config.seed_resolution_m));
  // Supervoxels with the octree's depth-dependent cell size (one camera at the origin).
  supervoxels.setUseSingleCameraTransform(true);
  supervoxels.setInputCloud(cloud);
  supervoxels.setColorImportance(0.0f);
  supervoxels.setSpatialImportance(1.0f);
  supervoxels.setNormalImportance(4.0f);
  std::map<std::uint32_t, pcl::Supervoxel<pcl::PointXYZ>::Ptr> clusters;
  supervoxels.extract(clusters);
  if (clusters.empty()) return out;
  std::multimap<std::uint32_t, std::uint32_t> adjacency;
  supervoxels.getSupervoxelAdjacency(adjacency);
  // The points' supervoxels here, their LCCP segments once relabelled below.
  pcl::PointCloud<pcl::PointXYZL>::Ptr labelled = supervoxels.getLabeledCloud();
  std::optional<ImageNeighbours> image;  // with depth steps or creases
  if (config.depth_jump_ratio > 0.0 || config.crease_angle_deg > 0.0)
    image.emplace(
        out, *cloud, config,
        config.crease_angle_deg > 0.0 ? concaveCreases(depth, camera, config) : Image<uint8_t>());
  if (config.depth_jump_ratio > 0.0)
    cutSteppedAdjacency(*image, *labelled, config.depth_jump_share, &adjacency);

  pcl::LCCPSegmentation<pcl::PointXYZ> lccp;
  lccp.setConcavityToleranceThreshold(static_cast<float>(config.concavity_tolerance_deg));
  // Both extra criteria cut the faces of one real box apart at a convex edge (measured on
  // the mOSD scenes), so they stay off.
  lccp.setSanityCheck(false);
  lccp.setSmoothnessCheck(false, static_cast<float>(config.voxel_resolution_m),
                          static_cast<float>(config.seed_resolution_m));
  lccp.setKFactor(1);         // extended convexity: one neighbour must confirm a convex edge
  lccp.setMinSegmentSize(0);  // merged below, in an order that does not depend on memory
  lccp.setInputSupervoxels(clusters, adjacency);
  lccp.segment();
  std::map<std::uint32_t, std::uint32_t> lccp_segment_of;
  lccp.getSupervoxelToSegmentMap(lccp_segment_of);
  std::map<std::uint32_t, std::set<std::uint32_t>> segment_adjacency;
  const auto segment_of = mergeSmallSegments(lccp_segment_of, adjacency, 3, &segment_adjacency);
  for (auto& p : labelled->points) {
    const auto it = segment_of.find(p.label);
    p.label = it == segment_of.end() ? 0u : it->second;  // 0: in no supervoxel
  }

  // Patches: LCCP segments with enough points, renumbered from 0.
  std::map<std::uint32_t, int> size;
  for (const auto& p : labelled->points)
    if (p.label != 0) ++size[p.label];
  // Numbered in the order of their first point: the regrouping breaks ties by patch order.
  std::map<std::uint32_t, int> index;
  for (const auto& p : labelled->points)
    if (p.label != 0 && size[p.label] >= config.min_segment_points && !index.count(p.label))
      index[p.label] = out.patches++;
  for (size_t i = 0; i < labelled->size() && i < out.patch.size(); ++i) {
    const auto it = index.find(labelled->points[i].label);
    if (it != index.end()) out.patch[i] = it->second;
  }
  // Patches that share an edge: LCCP kept them apart, so the edge is concave.
  std::set<std::pair<int, int>> concave;
  for (const auto& [a, neighbours] : segment_adjacency) {
    const auto ia = index.find(a);
    if (ia == index.end()) continue;
    for (std::uint32_t b : neighbours) {
      const auto ib = index.find(b);
      if (ib != index.end() && ib->second != ia->second)
        concave.insert(std::minmax(ia->second, ib->second));
    }
  }
  if (image) {
    splitPatches(*image, config.min_segment_points, &out, &concave);
    // Patches meeting across depth steps are apart as at a concave edge.
    if (config.depth_jump_ratio > 0.0)
      for (const auto& edge : steppedPairs<int>(*image, out.patch, -1, config.depth_jump_share))
        concave.insert(edge);
  }
  out.concave_edges.assign(concave.begin(), concave.end());
  return out;
}

int nearestLabelledVoxel(const Grid3<int>& labels, const Vec3& p, int reach) {
  const GridSpec& g = labels.spec;
  const Vec3i c = g.voxelIndex(p);
  int best = -1;
  double best_d = std::numeric_limits<double>::infinity();
  for (int dz = -reach; dz <= reach; ++dz)
    for (int dy = -reach; dy <= reach; ++dy)
      for (int dx = -reach; dx <= reach; ++dx) {
        const int x = c.x() + dx, y = c.y() + dy, z = c.z() + dz;
        if (!g.inside(x, y, z)) continue;
        const int i = g.linear(x, y, z);
        if (labels.data[i] < 0) continue;
        const double d = (g.voxelCentre(x, y, z) - p).squaredNorm();
        if (d < best_d) {
          best_d = d;
          best = i;
        }
      }
  return best;
}

double seenFreeShare(const SurfaceSegments& s, const std::vector<int>& a, const std::vector<int>& b,
                     const SurfaceSegmentConfig& config, uint64_t seed) {
  if (a.empty() || b.empty()) return 0.0;
  std::mt19937_64 rng(seed);
  std::uniform_int_distribution<size_t> pick_a(0, a.size() - 1), pick_b(0, b.size() - 1);
  std::uniform_real_distribution<double> along(0.1, 0.9);
  const Transform T_camera_table = s.T_table_camera.inverse();
  int checked = 0, free = 0;
  for (int i = 0; i < config.hull_samples; ++i) {
    const Vec3& pa = s.points_table[a[pick_a(rng)]];
    const Vec3& pb = s.points_table[b[pick_b(rng)]];
    const Vec3 q = T_camera_table * (pa + along(rng) * (pb - pa));
    double u, v;
    if (!s.camera.project(q, &u, &v)) continue;
    const int iu = static_cast<int>(std::lround(u)), iv = static_cast<int>(std::lround(v));
    if (iu < 0 || iv < 0 || iu >= s.depth.width || iv >= s.depth.height) continue;
    const float d = s.depth.at(iu, iv);
    if (!validDepth(d)) continue;
    ++checked;
    free += q.z() < d - config.free_space_margin_m;
  }
  return checked > 0 ? static_cast<double>(free) / checked : 0.0;
}

namespace {

/// Disjoint sets of 0..n-1 (union-find with path halving).
class DisjointSets {
 public:
  explicit DisjointSets(int n) : root_(n) { std::iota(root_.begin(), root_.end(), 0); }
  int find(int k) {
    while (root_[k] != k) k = root_[k] = root_[root_[k]];
    return k;
  }
  void join(int a, int b) { root_[find(a)] = find(b); }

 private:
  std::vector<int> root_;
};

/// Calls f(v, w, axis, a, b) for every voxel face between two labelled voxels of different
/// labels: voxel v (label a) and its neighbour w = v + 1 along `axis` (label b).
template <class F>
void forEachLabelFace(const Grid3<int>& labels, F&& f) {
  const GridSpec& g = labels.spec;
  for (int v = 0; v < g.voxelCount(); ++v) {
    const int a = labels.data[v];
    if (a < 0) continue;
    const Vec3i c = g.unravel(v);
    for (int axis = 0; axis < 3; ++axis) {
      Vec3i n = c;
      ++n[axis];
      if (!g.inside(n.x(), n.y(), n.z())) continue;
      const int w = g.linear(n.x(), n.y(), n.z());
      const int b = labels.data[w];
      if (b >= 0 && b != a) f(v, w, axis, a, b);
    }
  }
}

/// Per point: its labelled voxel (nearestLabelledVoxel), -1 none.
std::vector<int> pointVoxels(const SurfaceSegments& segments, const Grid3<int>& labels) {
  std::vector<int> out(segments.points_table.size());
  for (size_t i = 0; i < out.size(); ++i)
    out[i] = nearestLabelledVoxel(labels, segments.points_table[i]);
  return out;
}

/// The visible points of every (instance, patch) pair, and the voxel each point falls in.
struct VisibleParts {
  std::vector<std::map<int, std::vector<int>>> seen;  ///< per instance: patch -> point indices
  std::vector<int> visible;                           ///< per instance: its visible points
  std::vector<int> voxel_of;                          ///< per point: its labelled voxel, -1 none
};

/// `voxel_of`: the points' labelled voxels (pointVoxels), which relabelling the instances keeps.
VisibleParts visibleParts(const SurfaceSegments& segments, const Grid3<int>& labels, int instances,
                          std::vector<int> voxel_of) {
  VisibleParts out;
  out.seen.resize(instances);
  out.visible.assign(instances, 0);
  out.voxel_of = std::move(voxel_of);
  for (size_t i = 0; i < segments.points_table.size(); ++i) {
    const int v = out.voxel_of[i];
    if (v < 0) continue;
    const int k = labels.data[v];
    ++out.visible[k];
    if (segments.patch[i] >= 0) out.seen[k][segments.patch[i]].push_back(static_cast<int>(i));
  }
  return out;
}

/// Whether two instances may be one object, by their votes where they meet: the votes of one
/// object cut in two point across the cut towards its centre, those of two objects away from
/// each other. Without votes every pair may join.
class JoinTest {
 public:
  JoinTest(const Grid3<int>& labels, const Grid3<Vec3f>* votes, const SurfaceSegmentConfig& config)
      : labels_(labels), votes_(votes), config_(config) {}

  bool mayJoin(int a, int b) {
    if (!votes_ || config_.apart_vote_divergence >= 1.0) return true;
    const auto key = std::minmax(a, b);
    if (!measured_) measure();
    const auto it = divergence_.find(key);
    if (it == divergence_.end() || it->second.second < config_.min_boundary_faces) return true;
    return it->second.first / it->second.second <= config_.apart_vote_divergence;
  }

 private:
  /// Per pair of labels that share voxel faces: the sum over the faces of how far the two
  /// unit votes point away from each other across the face, and the face count.
  void measure() {
    measured_ = true;
    forEachLabelFace(labels_, [&](int v, int w, int axis, int a, int b) {
      const Vec3f va = votes_->data[v], vb = votes_->data[w];
      if (!(va.norm() > 1e-6f && vb.norm() > 1e-6f)) return;
      // Along +axis from v to w: v's vote towards w is +va[axis], w's towards v is -vb[axis].
      auto& [sum, faces] = divergence_[std::minmax(a, b)];
      sum += 0.5 * (vb[axis] / vb.norm() - va[axis] / va.norm());
      ++faces;
    });
  }

  const Grid3<int>& labels_;
  const Grid3<Vec3f>* votes_;
  const SurfaceSegmentConfig& config_;
  std::map<std::pair<int, int>, std::pair<double, int>> divergence_;
  bool measured_ = false;
};

/// The instances a patch is part of, in the sets that may join (JoinTest): connected through
/// pairs that may join.
std::vector<std::set<int>> joinableSets(const std::set<int>& instances, JoinTest* test) {
  const std::vector<int> k(instances.begin(), instances.end());
  const int n = static_cast<int>(k.size());
  DisjointSets joined(n);
  for (int i = 0; i < n; ++i)
    for (int j = i + 1; j < n; ++j)
      if (joined.find(i) != joined.find(j) && test->mayJoin(k[i], k[j])) joined.join(j, i);
  std::map<int, std::set<int>> sets;
  for (int i = 0; i < n; ++i) sets[joined.find(i)].insert(k[i]);
  std::vector<std::set<int>> out;
  for (auto& [r, set] : sets) out.push_back(std::move(set));
  return out;
}

struct PatchGroup {
  std::vector<int> points;  ///< visible points (indices), all the group's patches
  std::set<int> instances;
  std::vector<int> patches;
};

/// One group per patch that makes up a real share of some instance's visible surface, with
/// the instances it is part of; of instances that may not join (JoinTest), the patch stays
/// part of the joinable set holding most of its points.
std::vector<PatchGroup> initialGroups(const SurfaceSegments& segments, const VisibleParts& parts,
                                      const SurfaceSegmentConfig& config, JoinTest* join_test) {
  const int instances = static_cast<int>(parts.seen.size());
  std::vector<std::set<int>> part_of(segments.patches);
  for (int k = 0; k < instances; ++k)
    for (const auto& [p, points] : parts.seen[k])
      if (points.size() >= static_cast<size_t>(config.min_segment_points) &&
          points.size() >= config.min_instance_share * parts.visible[k])
        part_of[p].insert(k);
  // Slivers: most of an instance's few visible points on a patch of another instance.
  const std::vector<std::set<int>> regular = part_of;
  for (int k = 0; k < instances; ++k)
    for (const auto& [p, points] : parts.seen[k])
      if (!regular[p].empty() && points.size() >= config.fragment_share * parts.visible[k])
        part_of[p].insert(k);
  std::vector<PatchGroup> groups;
  for (int p = 0; p < segments.patches; ++p) {
    if (part_of[p].empty()) continue;
    PatchGroup grp;
    for (std::set<int>& instances : joinableSets(part_of[p], join_test)) {
      std::vector<int> points;
      for (int k : instances) {
        const std::vector<int>& pts = parts.seen[k].at(p);
        points.insert(points.end(), pts.begin(), pts.end());
      }
      if (points.size() <= grp.points.size()) continue;
      grp.points = std::move(points);
      grp.instances = std::move(instances);
    }
    grp.patches = {p};
    groups.push_back(std::move(grp));
  }
  return groups;
}

/// `labels` with every instance the camera did not see (fewer than `max_unseen` visible points)
/// joined to the instance it shares the most voxel faces with (chains of unseen instances end
/// in one label); true when any was joined.
bool joinUnseen(const std::vector<int>& visible, int max_unseen, Grid3<int>* labels) {
  const int instances = static_cast<int>(visible.size());
  std::vector<std::map<int, int>> faces(instances);
  forEachLabelFace(*labels, [&](int, int, int, int a, int b) {
    ++faces[a][b];
    ++faces[b][a];
  });
  DisjointSets sets(instances);
  bool joined = false;
  for (int k = 0; k < instances; ++k) {
    if (visible[k] >= max_unseen || faces[k].empty()) continue;
    const auto most =
        std::max_element(faces[k].begin(), faces[k].end(),
                         [](const auto& a, const auto& b) { return a.second < b.second; });
    sets.join(k, most->first);
    joined = true;
  }
  if (!joined) return false;
  for (int& l : labels->data)
    if (l >= 0) l = sets.find(l);
  return true;
}

/// Whether two groups' heights overlap over most of the shorter span (10th to 90th
/// percentile): a cup's inside and outside do, one object resting on another does not.
bool sideBySide(const SurfaceSegments& segments, const PatchGroup& a, const PatchGroup& b) {
  const auto span = [&](const PatchGroup& g) {
    std::vector<double> z;
    for (int i : g.points) z.push_back(segments.points_table[i].z());
    std::sort(z.begin(), z.end());
    return std::make_pair(z[z.size() / 10], z[(z.size() * 9) / 10]);
  };
  const auto [a0, a1] = span(a);
  const auto [b0, b1] = span(b);
  return std::min(a1, b1) - std::max(a0, b0) > 0.5 * std::min(a1 - a0, b1 - b0);
}

/// The point the votes of a group's visible voxels point at: the least-squares meeting point
/// of the lines through each voxel centre along its vote; nullopt when the lines are (near)
/// parallel or no voxel has a vote.
std::optional<Vec3> voteCentre(const PatchGroup& group, const std::vector<int>& voxel_of,
                               const Grid3<Vec3f>& votes) {
  const GridSpec& g = votes.spec;
  Mat3 A = Mat3::Zero();
  Vec3 b = Vec3::Zero();
  std::set<int> voxels;
  for (int i : group.points)
    if (voxel_of[i] >= 0) voxels.insert(voxel_of[i]);
  for (int v : voxels) {
    const Vec3f d = votes.data[v];
    if (!(d.norm() > 1e-6f)) continue;
    const Vec3 u = d.cast<double>().normalized();
    const Vec3i c = g.unravel(v);
    const Mat3 P = Mat3::Identity() - u * u.transpose();  // distance across the line
    A += P;
    b += P * g.voxelCentre(c.x(), c.y(), c.z());
  }
  const Eigen::SelfAdjointEigenSolver<Mat3> eig(A);
  if (voxels.empty() || !(eig.eigenvalues()(0) > 1e-3 * eig.eigenvalues()(2))) return std::nullopt;
  return Vec3(A.ldlt().solve(b));
}

/// Two groups that share an instance join when they do not meet at a concave edge and the hull
/// of their points is not seen as free space, or, meeting at one, when they stand side by side
/// and the network's votes of their visible voxels meet at one point (`same_centre_m`, needs
/// `votes`); the vote-sharing pairs first, then the least free, until none joins.
void joinGroups(const SurfaceSegments& segments, const SurfaceSegmentConfig& config,
                std::vector<PatchGroup>* groups_io, const std::vector<int>& voxel_of,
                const Grid3<Vec3f>* votes) {
  std::vector<PatchGroup>& groups = *groups_io;
  const std::set<std::pair<int, int>> concave_edges(segments.concave_edges.begin(),
                                                    segments.concave_edges.end());
  for (;;) {
    int best_a = -1, best_b = -1;
    double best = config.max_free_share;
    for (size_t a = 0; a < groups.size(); ++a)
      for (size_t b = a + 1; b < groups.size(); ++b) {
        bool shared = false, concave = false;
        for (int k : groups[a].instances) shared |= groups[b].instances.count(k) > 0;
        for (int pa : groups[a].patches)
          for (int pb : groups[b].patches) concave |= concave_edges.count(std::minmax(pa, pb)) > 0;
        if (!shared) continue;
        bool same_centre = false;
        if (concave && votes && config.same_centre_m > 0 &&
            sideBySide(segments, groups[a], groups[b])) {
          const auto ca = voteCentre(groups[a], voxel_of, *votes);
          const auto cb = voteCentre(groups[b], voxel_of, *votes);
          same_centre = ca && cb && (*ca - *cb).norm() <= config.same_centre_m;
        }
        if (concave && !same_centre) continue;
        // Groups whose votes meet at one point are one object, whatever the hull: a cup's
        // inside and outside, seen through its opening, first.
        const double share = same_centre ? -1.0
                                         : seenFreeShare(segments, groups[a].points,
                                                         groups[b].points, config, 7919u * a + b);
        if (share <= best) {
          best = share;
          best_a = static_cast<int>(a);
          best_b = static_cast<int>(b);
        }
      }
    if (best_a < 0) return;
    PatchGroup& into = groups[best_a];
    const PatchGroup& from = groups[best_b];
    into.points.insert(into.points.end(), from.points.begin(), from.points.end());
    into.instances.insert(from.instances.begin(), from.instances.end());
    into.patches.insert(into.patches.end(), from.patches.begin(), from.patches.end());
    groups.erase(groups.begin() + best_b);
  }
}

/// The group of every voxel of a grouped instance: the group whose visible voxels it reaches
/// first, moving through voxels of the same instance (6-connected); -1 where none does.
std::vector<int> growGroups(const Grid3<int>& labels, const std::vector<PatchGroup>& groups,
                            const std::vector<int>& voxel_of) {
  const GridSpec& g = labels.spec;
  std::vector<int> owner(labels.data.size(), -1);
  std::deque<int> queue;
  for (size_t j = 0; j < groups.size(); ++j)
    for (int i : groups[j].points) {
      const int v = voxel_of[i];
      if (owner[v] >= 0 || !groups[j].instances.count(labels.data[v])) continue;
      owner[v] = static_cast<int>(j);
      queue.push_back(v);
    }
  while (!queue.empty()) {
    const int v = queue.front();
    queue.pop_front();
    const Vec3i at = g.unravel(v);
    const int x = at.x(), y = at.y(), z = at.z();
    const int next[6][3] = {{x - 1, y, z}, {x + 1, y, z}, {x, y - 1, z},
                            {x, y + 1, z}, {x, y, z - 1}, {x, y, z + 1}};
    for (const auto& c : next) {
      if (!g.inside(c[0], c[1], c[2])) continue;
      const int w = g.linear(c[0], c[1], c[2]);
      if (labels.data[w] != labels.data[v] || owner[w] >= 0) continue;
      owner[w] = owner[v];
      queue.push_back(w);
    }
  }
  return owner;
}

/// New labels: per instance, the group owning most of its voxels takes the ones no group
/// reached, and the voxels of a group left with fewer than `min_part_voxels`; the groups that
/// keep enough voxels come first, then the instances no group took. Centres are the new parts'
/// voxel means.
void relabel(const Grid3<int>& labels, const std::vector<int>& owner, int groups, int instances,
             int min_part_voxels, InstanceSegmentation* out) {
  const GridSpec& g = labels.spec;
  const int n = static_cast<int>(labels.data.size());
  std::vector<std::map<int, int>> owned(instances);
  for (int v = 0; v < n; ++v)
    if (labels.data[v] >= 0 && owner[v] >= 0) ++owned[labels.data[v]][owner[v]];
  std::vector<int> group_voxels(groups, 0);
  for (int v = 0; v < n; ++v)
    if (owner[v] >= 0) ++group_voxels[owner[v]];
  std::vector<int> main_group(instances, -1);
  for (int k = 0; k < instances; ++k) {
    int most = 0;
    for (const auto& [j, count] : owned[k])
      if (group_voxels[j] >= min_part_voxels && count > most) {
        most = count;
        main_group[k] = j;
      }
  }
  std::vector<int> label_of_group(groups, -1), label_of_instance(instances, -1);
  int next_label = 0;
  for (int v = 0; v < n; ++v) {
    const int k = labels.data[v];
    if (k < 0) continue;
    int j = owner[v];
    if (j >= 0 && group_voxels[j] < min_part_voxels) j = -1;
    if (j < 0) j = main_group[k];
    int& label = j >= 0 ? label_of_group[j] : label_of_instance[k];
    if (label < 0) label = next_label++;
    out->labels.data[v] = label;
  }
  out->centres_table.assign(next_label, Vec3::Zero());
  out->voxel_counts.assign(next_label, 0);
  for (int v = 0; v < n; ++v) {
    const int l = out->labels.data[v];
    if (l < 0) continue;
    const Vec3i c = g.unravel(v);
    out->centres_table[l] += g.voxelCentre(c.x(), c.y(), c.z());
    ++out->voxel_counts[l];
  }
  for (int l = 0; l < next_label; ++l) out->centres_table[l] /= out->voxel_counts[l];
}

}  // namespace

InstanceSegmentation regroupAlongSurfaceSegments(const SurfaceSegments& segments,
                                                 const SurfaceSegmentConfig& config,
                                                 int min_part_voxels,
                                                 const InstanceSegmentation& hough,
                                                 const Grid3<Vec3f>* votes) {
  config.validate();
  if (votes && votes->data.size() != hough.labels.data.size())
    throw std::invalid_argument(
        "regroupAlongSurfaceSegments: the votes' grid (" + std::to_string(votes->data.size()) +
        " voxels) is not the instances' (" + std::to_string(hough.labels.data.size()) + ")");
  InstanceSegmentation out = hough;
  const int instances = hough.size();
  if (instances < 1) return out;
  Grid3<int> labels = hough.labels;
  VisibleParts parts = visibleParts(segments, labels, instances, pointVoxels(segments, labels));
  const bool joined = joinUnseen(parts.visible, config.max_unseen_points, &labels);
  if (joined) parts = visibleParts(segments, labels, instances, std::move(parts.voxel_of));
  JoinTest join_test(labels, votes, config);
  std::vector<PatchGroup> groups = initialGroups(segments, parts, config, &join_test);
  if (groups.empty() && !joined) return out;
  joinGroups(segments, config, &groups, parts.voxel_of, votes);
  const std::vector<int> owner = growGroups(labels, groups, parts.voxel_of);
  relabel(labels, owner, static_cast<int>(groups.size()), instances, min_part_voxels, &out);
  return out;
}

}  // namespace simstack
