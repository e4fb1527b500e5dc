#include "simstack/pipeline/scene_perception.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <map>
#include <mutex>
#include <optional>
#include <random>
#include <sstream>
#include <stdexcept>
#include <thread>
#include <tuple>
#include <utility>

#include <opencv2/imgproc.hpp>

#include "simstack/geometry/superquadric.h"
#include "simstack/instances/instance_finder.h"
#include "simstack/instances/surface_instances.h"
#include "simstack/io/config_fields.h"
#include "simstack/mesh/marching_cubes.h"
#include "simstack/mesh/mesh_ops.h"
#include "simstack/model/cvae_inference.h"
#include "simstack/model/model_integrity.h"
#include "simstack/pipeline/workspace.h"
#include "simstack/render/depth_renderer.h"
#include "simstack/render/visibility.h"
#include "simstack/tsdf/network_input.h"
#include "simstack/tsdf/projective_tsdf.h"

namespace simstack {
namespace {

using Clock = std::chrono::steady_clock;
double msSince(Clock::time_point t) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t).count();
}

void checkPose(const Transform& T, size_t index) {
  const std::string name = "view " + std::to_string(index) + ": the camera pose ";
  if (!T.matrix().allFinite()) throw std::invalid_argument(name + "is not finite");
  const Mat3 R = T.linear();
  if (!(R.transpose() * R).isIdentity(1e-4) || std::abs(R.determinant() - 1.0) > 1e-4)
    throw std::invalid_argument(name + "is not rigid (its rotation is not orthonormal)");
  if (!(T.translation().z() > 0.0))
    throw std::invalid_argument(name + "puts the camera " + std::to_string(T.translation().z()) +
                                " m above the table; it must be above it");
  // A low camera may look slightly up at a tall pile; one looking more than 45 degrees up
  // cannot see the table (a pose given the wrong way round).
  if (!(R.col(2).z() < std::sqrt(0.5)))
    throw std::invalid_argument(
        name + "looks away from the table (its optical axis points " +
        std::to_string(std::asin(std::min(1.0, R.col(2).z())) * 180 / M_PI) + " degrees up)");
}

/// The smallest depth image perceived: a pile seen by fewer pixels is no scene.
constexpr int kMinImageSide = 16;
/// The least share of the first view's pixels with a depth: a camera that sees less has lost
/// sight of the scene (covered, too close, dazzled) and would report the pile gone.
constexpr double kMinValidShare = 0.01;

void checkView(const DepthView& v, size_t index) {
  if (v.depth.width < kMinImageSide || v.depth.height < kMinImageSide)
    throw std::invalid_argument("view " + std::to_string(index) + ": the depth image is " +
                                std::to_string(v.depth.width) + "x" +
                                std::to_string(v.depth.height) + ": at least " +
                                std::to_string(kMinImageSide) + " pixels each way");
  v.camera.validate();
  if (v.T_table_camera) checkPose(*v.T_table_camera, index);
  if (v.depth.width != v.camera.width || v.depth.height != v.camera.height ||
      v.depth.pixels.size() != static_cast<size_t>(v.depth.width) * v.depth.height)
    throw std::invalid_argument(
        "view " + std::to_string(index) + ": the depth image is " + std::to_string(v.depth.width) +
        "x" + std::to_string(v.depth.height) + " but its camera is " +
        std::to_string(v.camera.width) + "x" + std::to_string(v.camera.height));
  if (!v.mask.empty() && (v.mask.width != v.depth.width || v.mask.height != v.depth.height ||
                          v.mask.pixels.size() != v.depth.pixels.size()))
    throw std::invalid_argument("view " + std::to_string(index) + ": the mask is " +
                                std::to_string(v.mask.width) + "x" + std::to_string(v.mask.height) +
                                " but the depth image is " + std::to_string(v.depth.width) + "x" +
                                std::to_string(v.depth.height));
}

/// The views with depth outside the sensor's range or the view's mask marked missing (a float
/// image of random bits holds depths of 1e30 m); a first view with nothing left is unusable.
std::vector<DepthView> withinSensorRange(const std::vector<DepthView>& views,
                                         const PerceptionConfig& c) {
  std::vector<DepthView> out = views;
  for (size_t i = 0; i < out.size(); ++i) {
    const size_t pixels = views[i].depth.pixels.size();
    const size_t given = std::count_if(views[i].depth.pixels.begin(), views[i].depth.pixels.end(),
                                       [](float d) { return d > 0.0f && std::isfinite(d); });
    if (i == 0 && given > 0 && given < kMinValidShare * pixels)
      throw std::invalid_argument(
          "view 0 holds " + std::to_string(given) + " depths in its " + std::to_string(pixels) +
          " pixels (under " + std::to_string(static_cast<int>(100 * kMinValidShare)) +
          " %): a camera that lost sight of the scene (covered, too close, dazzled?)");
    applyMask(&out[i]);
    size_t valid = 0;
    float lo = std::numeric_limits<float>::infinity(), hi = 0.0f;  // of the depths given
    for (float& d : out[i].depth.pixels) {
      if (d > 0.0f && std::isfinite(d)) lo = std::min(lo, d), hi = std::max(hi, d);
      if (!(d >= c.min_depth_m && d <= c.max_depth_m)) d = 0.0f;
      valid += d > 0.0f;
    }
    if (i == 0 && valid == 0) {
      std::ostringstream why;
      why << "view 0 has no depth within the sensor range " << c.min_depth_m << " .. "
          << c.max_depth_m << " m" << (out[i].mask.empty() ? "" : " and its mask");
      if (hi > 0.0f) why << " (its depths span " << lo << " .. " << hi << " m";
      if (hi > 0.0f && lo >= 100.0f && hi <= 20000.0f)  // 0.1-20 m, read as metres
        why << ": millimetres where metres are expected?";
      if (hi > 0.0f) why << ")";
      throw std::invalid_argument(why.str());
    }
  }
  return out;
}

/// Each instance's visible share: its triangles that are the first surface a ray from the
/// camera meets, among all instances' triangles.
void setVisibleFractions(SceneHypothesis* h, const PinholeCamera& camera,
                         const Transform& T_table_camera) {
  TriangleMesh all;
  std::vector<int> owner;
  for (size_t k = 0; k < h->instances.size(); ++k) {
    all.append(h->instances[k].mesh);
    owner.resize(all.triangles.size(), static_cast<int>(k));
  }
  if (all.empty()) return;
  const std::vector<bool> seen = visibleTriangles(all, camera, T_table_camera);
  std::vector<double> area(h->instances.size(), 0.0), visible(h->instances.size(), 0.0);
  for (size_t i = 0; i < all.triangles.size(); ++i) {
    const double a = all.triangleArea(i);
    area[owner[i]] += a;
    if (seen[i]) visible[owner[i]] += a;
  }
  for (size_t k = 0; k < h->instances.size(); ++k)
    h->instances[k].visible_fraction = area[k] > 0 ? visible[k] / area[k] : 0.0;
}

/// `n` samples of each instance's mesh (none for an empty one).
std::vector<Points3> fitPoints(const std::vector<TriangleMesh>& parts, int n, uint64_t seed) {
  std::vector<Points3> points(parts.size());
  for (size_t k = 0; k < parts.size(); ++k) {
    std::mt19937_64 rng(seed * 7919 + k);
    for (const SurfacePoint& s : parts[k].sampleSurface(n, rng)) points[k].push_back(s.position);
  }
  return points;
}

/// Each instance's points for the fitter: the views' depth points lying on its voxels (at most
/// `n`), and `n` times the unseen share of its mesh's area in samples of the unseen part (the
/// triangles that no ray from a view's camera meets first). The measured points outnumber the seen
/// part's share of `n`: they are the surface itself, where the network's mesh is up to a voxel off,
/// and the fits weigh them accordingly (docs/experiments.md, "Fitting"). When the views hold fewer
/// of them than that share, samples of the seen mesh make up the difference. `measured_all`:
/// every depth point on each instance's voxels, of which the fitter takes at most `n`.
std::vector<Points3> fitPoints(const std::vector<TriangleMesh>& parts, const Grid3<int>& labels,
                               const std::vector<MeasuredView>& views, int n, uint64_t seed,
                               std::vector<int>* measured_counts,
                               std::vector<Points3>* measured_all) {
  TriangleMesh all;
  std::vector<size_t> first(parts.size() + 1, 0);
  for (size_t k = 0; k < parts.size(); ++k) {
    all.append(parts[k]);
    first[k + 1] = all.triangles.size();
  }
  std::vector<bool> seen(all.triangles.size(), false);
  std::vector<Points3> measured(parts.size());
  for (const MeasuredView& view : views) {
    const std::vector<bool> seen_here = visibleTriangles(all, view.camera, view.T_table_camera);
    for (size_t i = 0; i < seen.size(); ++i) seen[i] = seen[i] || seen_here[i];
    for (const Vec3& p : view.points_table) {
      const int voxel = nearestLabelledVoxel(labels, p);
      const int k = voxel >= 0 ? labels.data[voxel] : -1;
      if (k >= 0 && k < static_cast<int>(parts.size())) measured[k].push_back(p);
    }
  }
  *measured_all = measured;
  std::vector<Points3> points(parts.size());
  measured_counts->assign(parts.size(), 0);
  for (size_t k = 0; k < parts.size(); ++k) {
    std::mt19937_64 rng(seed * 7919 + k);
    if (parts[k].empty()) {  // found on the surface alone (surface_instances.h): what was seen
      points[k] = measured[k];
      std::shuffle(points[k].begin(), points[k].end(), rng);
      if (static_cast<int>(points[k].size()) > n) points[k].resize(n);
      (*measured_counts)[k] = static_cast<int>(points[k].size());
      continue;
    }
    std::vector<bool> seen_k(seen.begin() + first[k], seen.begin() + first[k + 1]), unseen_k;
    double area = 0, seen_area = 0;
    for (size_t i = 0; i < seen_k.size(); ++i) {
      const double a = parts[k].triangleArea(i);
      area += a;
      seen_area += seen_k[i] ? a : 0.0;
      unseen_k.push_back(!seen_k[i]);
    }
    const int n_seen = area > 0 ? static_cast<int>(std::lround(n * seen_area / area)) : 0;
    Points3& m = measured[k];
    std::shuffle(m.begin(), m.end(), rng);
    if (static_cast<int>(m.size()) > n) m.resize(n);
    points[k] = m;
    (*measured_counts)[k] = static_cast<int>(m.size());
    const int from_seen_mesh = std::max(0, n_seen - static_cast<int>(m.size()));
    for (const SurfacePoint& s : subMesh(parts[k], seen_k).sampleSurface(from_seen_mesh, rng))
      points[k].push_back(s.position);
    for (const SurfacePoint& s : subMesh(parts[k], unseen_k).sampleSurface(n - n_seen, rng))
      points[k].push_back(s.position);
  }
  return points;
}

/// Joins, pair by pair (the largest overlap first), instances whose own fits overlap by
/// `surface_instances.fit_overlap_share` of the smaller one's volume, and fits each joined
/// instance again on both point sets. The per-instance arrays follow the segmentation's labels.
/// Returns the number of joins.
int joinOverlappingFits(const PerceptionConfig& config, const FitConfig& fit,
                        InstanceSegmentation* seg, std::vector<TriangleMesh>* parts,
                        std::vector<Points3>* points, std::vector<int>* measured_counts,
                        std::vector<Points3>* measured_all, std::vector<bool>* outside,
                        std::vector<std::optional<SuperquadricShape>>* fits) {
  const SurfaceInstanceConfig& c = config.surface_instances;
  if (!c.enabled || c.fit_overlap_share <= 0.0) return 0;
  int joins = 0;
  for (;;) {
    int keep = -1, drop = -1;
    double best = c.fit_overlap_share;
    for (int a = 0; a < seg->size(); ++a)
      for (int b = a + 1; b < seg->size(); ++b) {
        if (!(*fits)[a] || !(*fits)[b]) continue;
        const double share = sharedVolumeShare(*(*fits)[a], *(*fits)[b]);
        if (share >= best) {
          best = share;
          keep = a;
          drop = b;
        }
      }
    if (keep < 0) return joins;
    joinInstances(seg, keep, drop);
    (*parts)[keep].append((*parts)[drop]);
    parts->erase(parts->begin() + drop);
    // Measured depth points lead an instance's points (InstanceEstimate::measured_points): both
    // instances' measured points first, then both sets of samples of the predicted surface.
    const Points3& a = (*points)[keep];
    const Points3& b = (*points)[drop];
    const int ma = (*measured_counts)[keep], mb = (*measured_counts)[drop];
    Points3 joined(a.begin(), a.begin() + ma);
    joined.insert(joined.end(), b.begin(), b.begin() + mb);
    joined.insert(joined.end(), a.begin() + ma, a.end());
    joined.insert(joined.end(), b.begin() + mb, b.end());
    (*points)[keep] = std::move(joined);
    const Points3& kept = (*points)[keep];
    points->erase(points->begin() + drop);
    (*measured_counts)[keep] = ma + mb;
    measured_counts->erase(measured_counts->begin() + drop);
    (*measured_all)[keep].insert((*measured_all)[keep].end(), (*measured_all)[drop].begin(),
                                 (*measured_all)[drop].end());
    measured_all->erase(measured_all->begin() + drop);
    outside->erase(outside->begin() + drop);  // an instance left outside has no fit: never joined
    fits->erase(fits->begin() + drop);
    (*fits)[keep] = fitEachInstance({kept}, fit, config.min_instance_points).front();
    ++joins;
  }
}

/// Pixel (u, v)'s depth point in the table frame, when it is valid and at least
/// `min_height_m` above the table (the pile's pixels, not the table's).
std::optional<Vec3> pilePoint(const DepthView& view, const Transform& T_table_camera, int u, int v,
                              double min_height_m) {
  const float d = view.depth.at(u, v);
  if (!validDepth(d)) return std::nullopt;
  const Vec3 p = T_table_camera * view.camera.backproject(u, v, d);
  if (p.z() < min_height_m) return std::nullopt;
  return p;
}

}  // namespace

void decompose(SceneHypothesis* h, const PerceptionConfig& config, StageTimings* timings,
               const SurfaceSegments* segments, const std::vector<MeasuredView>& measured_views,
               const std::vector<Points3>& held) {
  auto t = Clock::now();
  HoughConfig hough = config.hough;
  hough.threads = std::max(1, config.threads);
  InstanceSegmentation seg =
      InstanceFinder(hough, config.segments, config.crowded).find(h->tsdf_m, h->votes, segments);
  // The first view's depth points that no instance explains: objects of their own.
  if (!measured_views.empty()) {
    const Points3& points = measured_views.front().points_table;
    const bool patched = segments && segments->points_table.size() == points.size();
    addSurfaceInstances(points, config.surface_instances, &seg,
                        patched ? &segments->patch : nullptr);
    joinOpenContainers(points, measured_views.front().T_table_camera.translation(),
                       config.surface_instances, &seg);
    joinHeldContainers(points, measured_views.front().T_table_camera.translation(), held,
                       config.surface_instances, &seg);
    joinOccludedPieces(points, measured_views.front().camera, measured_views.front().T_table_camera,
                       std::max(1, config.segments.pixel_stride), config.surface_instances, &seg);
    joinHeldOccludedPieces(
        points, measured_views.front().camera, measured_views.front().T_table_camera,
        std::max(1, config.segments.pixel_stride), held, config.surface_instances, &seg);
  }
  // An instance whose centre lies outside the workspace is not reported (its voxels are free),
  // unless the camera saw it inside: the depth points left are the workspace's, and an object
  // the workspace's edge cuts is completed past it (then reported, truncated).
  std::vector<bool> outside(seg.size(), false);
  for (int k = 0; k < seg.size(); ++k)
    outside[k] = !config.workspace.contains(seg.centres_table[k]);
  if (std::find(outside.begin(), outside.end(), true) != outside.end()) {
    std::vector<int> seen_inside(seg.size(), 0);
    for (const MeasuredView& view : measured_views)
      for (const Vec3& p : view.points_table) {
        const int voxel = nearestLabelledVoxel(seg.labels, p);
        const int k = voxel >= 0 ? seg.labels.data[voxel] : -1;
        if (k >= 0 && outside[k]) ++seen_inside[k];
      }
    for (int k = 0; k < seg.size(); ++k)
      outside[k] = outside[k] && seen_inside[k] < std::max(1, config.min_instance_points);
  }
  // The hypothesis's labels: the segmentation's, less the instances left outside.
  const auto keepInsideLabels = [&] {
    h->labels = seg.labels;
    for (int& label : h->labels.data)
      if (label >= 0 && outside[label]) label = -1;
  };
  keepInsideLabels();
  if (timings) timings->instances_ms += msSince(t);

  t = Clock::now();
  if (h->surface.empty()) h->surface = extractSurface(h->tsdf_m);
  std::vector<TriangleMesh> parts =
      splitByLabel(h->surface, triangleLabels(h->surface, h->labels), seg.size());
  for (size_t k = 0; k < parts.size(); ++k)
    if (outside[k]) parts[k] = TriangleMesh();
  std::vector<int> measured_counts(parts.size(), 0);
  std::vector<Points3> measured_all(parts.size());
  std::vector<Points3> points =
      config.observed_points && !measured_views.empty()
          ? fitPoints(parts, h->labels, measured_views, config.points_per_instance, config.seed,
                      &measured_counts, &measured_all)
          : fitPoints(parts, config.points_per_instance, config.seed);
  if (timings) timings->mesh_ms += msSince(t);

  t = Clock::now();
  FitConfig fit = config.fit;
  fit.threads = std::max(1, config.threads);
  std::vector<std::optional<SuperquadricShape>> fits =
      fitEachInstance(points, fit, config.min_instance_points);
  if (joinOverlappingFits(config, fit, &seg, &parts, &points, &measured_counts, &measured_all,
                          &outside, &fits) > 0)
    keepInsideLabels();
  if (config.joint_refinement) refineInstances(points, fit, &fits);
  h->instances.clear();
  std::vector<int> reported(parts.size(), -1);  // segmentation label -> index in instances
  for (size_t k = 0; k < parts.size(); ++k) {
    if (!fits[k]) continue;
    reported[k] = static_cast<int>(h->instances.size());
    InstanceEstimate e;
    e.superquadric = *fits[k];
    // An instance the network did not predict (found on the surface) is its superquadric.
    e.mesh = parts[k].empty() ? superquadricsMesh({*fits[k]}) : parts[k];
    e.points = points[k];
    e.measured_points = measured_counts[k];
    e.measured = std::move(measured_all[k]);
    e.vote_centre = seg.centres_table[k];
    e.voxels = seg.voxel_counts[k];
    h->instances.push_back(std::move(e));
  }
  // Label k + 1 in the published label image is instances[k]: the voxels of instances given no
  // superquadric (too few points, outside the workspace) are no object's.
  for (int& label : h->labels.data)
    if (label >= 0) label = reported[label];
  h->decomposed = true;
  if (timings) timings->fitting_ms += msSince(t);
}

MeasuredView measuredView(const DepthView& view, const Transform& T_table_camera,
                          const GridSpec& grid, const PerceptionConfig& config) {
  WorkspaceConfig box;
  for (int a = 0; a < 3; ++a) {
    box.min_m[a] = grid.origin_table[a];
    box.max_m[a] = grid.origin_table[a] + grid.extent_m();
  }
  return {view.camera, T_table_camera,
          pilePoints(view, T_table_camera, box, config.min_pile_height_m,
                     std::numeric_limits<double>::infinity(),
                     std::max(1, config.segments.pixel_stride))};
}

namespace {

/// Marks the instances of `h` whose pixels in the first view (`used`: masked and cropped) touch
/// the image border or a pixel `given` measured that `used` left out.
void markTruncated(SceneHypothesis* h, const DepthView& given, const DepthView& used,
                   const Transform& T_table_camera, double min_height_m) {
  const Grid3<int>& labels = h->labels;
  if (h->instances.empty() || static_cast<int>(labels.data.size()) != labels.spec.voxelCount())
    return;
  const int w = used.depth.width, ht = used.depth.height, b = kTruncationBorderPx;
  cv::Mat1b left_out(ht, w, uchar{0});
  bool any_left_out = false;
  for (int i = 0; i < w * ht; ++i)
    if (validDepth(given.depth.pixels[i]) && !validDepth(used.depth.pixels[i])) {
      left_out.data[i] = 1;  // a new Mat: continuous, row by row as the depth image
      any_left_out = true;
    }
  // The pixels left out and their 8 neighbours (outside the image counts as not left out).
  cv::Mat1b near_left_out;
  if (any_left_out) cv::dilate(left_out, near_left_out, cv::Mat());
  const auto nextToLeftOut = [&](int u, int v) { return near_left_out(v, u) != 0; };
  const auto mark = [&](int u, int v) {
    const std::optional<Vec3> p = pilePoint(used, T_table_camera, u, v, min_height_m);
    if (!p) return;
    const int i = nearestLabelledVoxel(labels, *p);
    if (i >= 0 && labels.data[i] < static_cast<int>(h->instances.size()))
      h->instances[labels.data[i]].truncated = true;
  };
  for (int v = 0; v < ht; ++v) {
    const bool border_row = v < b || v >= ht - b;
    if (border_row || any_left_out) {
      for (int u = 0; u < w; ++u)
        if (border_row || u < b || u >= w - b || nextToLeftOut(u, v)) mark(u, v);
    } else {  // nothing left out: only the border columns can cut an object
      for (int u = 0; u < std::min(b, w); ++u) {
        mark(u, v);
        mark(w - 1 - u, v);
      }
    }
  }
}

/// The pile's pixels that no tile holds (indices v * width + u), a cut the truncation test reads:
/// those above the tiles (a pile taller than a grid), and, when the plan is cropped (the pile
/// needed more than `max_tiles`), those beside them. Beside the tiles of a plan that is not
/// cropped lie only what the spread's percentiles leave out (flying pixels), and points beside
/// the tiles' footprint above their top are no pile (a wall, a robot), no cut object. Empty for
/// most frames.
std::vector<int> outsideTiles(const DepthView& view, const Transform& T_table_camera,
                              const TilePlan& plan, double min_height_m) {
  std::vector<int> out;
  if (plan.groups.empty() || plan.groups.front().tiles.empty()) return out;
  const GridSpec& tile = plan.groups.front().tiles.front();
  const double top_m = tile.origin_table.z() + tile.extent_m();
  const double middle_m = tile.origin_table.z() + 0.5 * tile.extent_m();
  const auto held = [&](const Vec3& p) {
    return std::any_of(plan.groups.begin(), plan.groups.end(),
                       [&](const TileGroup& g) { return groupWeight(g, p) > 0.0; });
  };
  for (int v = 0; v < view.depth.height; ++v)
    for (int u = 0; u < view.depth.width; ++u) {
      const std::optional<Vec3> p = pilePoint(view, T_table_camera, u, v, min_height_m);
      if (p && (p->z() < top_m ? plan.cropped && !held(*p) : held(Vec3(p->x(), p->y(), middle_m))))
        out.push_back(v * view.depth.width + u);
    }
  return out;
}

/// Labelled pixels in depth-continuous regions (4-neighbours whose depths differ by at most 2 %):
/// per pixel its region, -1 for unlabelled ones; `regions` receives their count.
Image<int> continuousRegions(const DepthImage& depth, const Image<int>& labels, int* regions) {
  Image<int> region(labels.width, labels.height, -1);
  *regions = 0;
  std::vector<int> stack;
  const auto joins = [&](int a, int b) {
    const float da = depth.pixels[a], db = depth.pixels[b];
    return labels.pixels[b] >= 0 && region.pixels[b] < 0 && std::abs(da - db) <= 0.02f * da;
  };
  for (size_t start = 0; start < labels.pixels.size(); ++start) {
    if (labels.pixels[start] < 0 || region.pixels[start] >= 0) continue;
    region.pixels[start] = *regions;
    stack.assign(1, static_cast<int>(start));
    while (!stack.empty()) {
      const int i = stack.back();
      stack.pop_back();
      const int u = i % labels.width, v = i / labels.width;
      const int next[4][2] = {{u - 1, v}, {u + 1, v}, {u, v - 1}, {u, v + 1}};
      for (const auto& n : next) {
        if (n[0] < 0 || n[1] < 0 || n[0] >= labels.width || n[1] >= labels.height) continue;
        const int j = n[1] * labels.width + n[0];
        if (!joins(i, j)) continue;
        region.pixels[j] = *regions;
        stack.push_back(j);
      }
    }
    ++*regions;
  }
  return region;
}

}  // namespace

void followDepthEdges(const DepthImage& depth, Image<int>* labels) {
  int regions = 0;
  const Image<int> region = continuousRegions(depth, *labels, &regions);
  // Pixels per (region, instance), and per instance its largest region.
  std::vector<std::map<int, int>> count(regions);
  std::map<int, std::pair<int, int>> home;  // instance -> (pixels, region)
  for (size_t i = 0; i < region.pixels.size(); ++i)
    if (region.pixels[i] >= 0) ++count[region.pixels[i]][labels->pixels[i]];
  for (int r = 0; r < regions; ++r)
    for (const auto& [k, n] : count[r])
      if (n > home[k].first) home[k] = {n, r};
  // In each region, an instance at home elsewhere and holding little of it is a spill across
  // the depth edge: its pixels go to the region's main instance.
  std::vector<int> main_instance(regions, -1);
  std::vector<int> total(regions, 0);
  for (int r = 0; r < regions; ++r) {
    int most = 0;
    for (const auto& [k, n] : count[r]) {
      total[r] += n;
      if (n > most) {
        most = n;
        main_instance[r] = k;
      }
    }
  }
  for (size_t i = 0; i < region.pixels.size(); ++i) {
    const int r = region.pixels[i];
    if (r < 0) continue;
    const int k = labels->pixels[i];
    if (k != main_instance[r] && home[k].second != r && count[r][k] < kSpillShare * total[r])
      labels->pixels[i] = main_instance[r];
  }
}

Image<int> pixelInstances(const DepthView& view, const SceneEstimate& est, int hypothesis,
                          double min_height_m) {
  Image<int> out(view.depth.width, view.depth.height, -1);
  if (hypothesis < 0 || hypothesis >= static_cast<int>(est.hypotheses.size())) return out;
  const Grid3<int>& labels = est.hypotheses[hypothesis].labels;
  const GridSpec& g = labels.spec;
  if (static_cast<int>(labels.data.size()) != g.voxelCount()) return out;
  const Transform T_table_camera = view.T_table_camera.value_or(est.T_table_camera);
  for (int v = 0; v < view.depth.height; ++v)
    for (int u = 0; u < view.depth.width; ++u) {
      const std::optional<Vec3> p = pilePoint(view, T_table_camera, u, v, min_height_m);
      const int i = p ? nearestLabelledVoxel(labels, *p) : -1;
      if (i >= 0) out.at(u, v) = labels.data[i];
    }
  followDepthEdges(view.depth, &out);
  return out;
}

struct ScenePerception::Impl {
  PerceptionConfig config;
  std::unique_ptr<CvaeInference> model;
  std::string model_path;  ///< as config's, but never written after construction
  int threads = 1;         ///< the same
  std::mutex mutex;        ///< one perceive() or updateSettings() at a time: one model state
};

namespace {

/// More threads than cores only make the OpenMP regions and torch slower (1000 threads never
/// finish a frame).
int cappedThreads(int threads) {
  return std::min(threads, static_cast<int>(std::max(1u, std::thread::hardware_concurrency())));
}

/// The most the hypotheses of one frame may take (GB): more is a setting no machine holds.
constexpr double kMaxHypothesesGB = 4.0;

/// `c` for a grid of side `side_m`, its Hough radii and tile overlap chosen for the model's
/// side `model_side_m`: those lengths scaled with the side (GridConfig).
PerceptionConfig scaledToSide(PerceptionConfig c, double side_m, double model_side_m) {
  const double ratio = side_m / model_side_m;
  c.hough.bandwidth_m *= ratio;
  c.crowded.bandwidth_m *= ratio;
  c.workspace.tile_overlap_m *= ratio;
  return c;
}

/// `config` checked against the model it runs with: a tile overlap under half the grid, the
/// widest tiled grid within the Hough voting's fine cells and its hypotheses within
/// kMaxHypothesesGB, the thread count capped; a model
/// without a latent code draws one sample (S hypotheses would be S copies of one) and refuses
/// decompose_samples above 1. Throws std::invalid_argument naming the field.
PerceptionConfig forModel(PerceptionConfig config, const CvaeConfig& model) {
  // The overlap in whole voxels, as planTiles takes it.
  const double voxel = model.extent_m / model.resolution;
  if (std::ceil(config.workspace.tile_overlap_m / voxel - 1e-9) >= model.resolution / 2)
    throw std::invalid_argument("workspace: tile_overlap_m (" +
                                std::to_string(config.workspace.tile_overlap_m) +
                                " m) must be less than half the model's grid side (" +
                                std::to_string(0.5 * model.extent_m) + " m, in whole voxels)");
  // The widest scene the tiles make: a square of ceil(sqrt(max_tiles)) tiles (planTiles).
  const int widest =
      static_cast<int>(std::ceil(std::sqrt(config.workspace.max_tiles))) * model.resolution;
  if (widest * config.hough.refinement > kMaxHoughFineCells)
    throw std::invalid_argument("workspace.max_tiles " +
                                std::to_string(config.workspace.max_tiles) +
                                " and hough.refinement " + std::to_string(config.hough.refinement) +
                                ": the widest scene grid (" + std::to_string(widest) +
                                " voxels a side) times the "
                                "refinement must be at most " +
                                std::to_string(kMaxHoughFineCells) + "; lower one of them");
  // The Hough radii in the grids a frame may be perceived in, scaled from the model's side.
  const double first = config.grid.side_m > 0.0 ? config.grid.side_m : model.extent_m;
  std::vector<double> sides{first};
  if (config.grid.object_voxels > 0.0) sides.push_back(first * config.grid.fine_side_share);
  for (const double side : sides) {
    if (side < 0.01)
      throw std::invalid_argument("grid: the finer pass's side, " + configValue(side) +
                                  " m, is below 0.01 m; raise grid.fine_side_share or side_m");
    try {
      const PerceptionConfig scaled = scaledToSide(config, side, model.extent_m);
      scaled.hough.validate();
      scaled.crowded.validate();
    } catch (const std::invalid_argument& e) {
      throw std::invalid_argument("grid: in a grid of side " + configValue(side) +
                                  " m, the Hough radii scaled from the model's " +
                                  configValue(model.extent_m) + " m: " + e.what());
    }
  }
  config.threads = cappedThreads(config.threads);
  if (!model.hasLatentCode()) {
    // Its one scene would be decomposed once and handed on as if it were several hypotheses.
    if (config.decompose_samples > 1)
      throw std::invalid_argument(
          "decompose_samples " + std::to_string(config.decompose_samples) + ": the model (" +
          model.architecture +
          ") has no latent code and draws one scene; more than 1 needs a model with one (the "
          "C-VAE, models/simstack_r32.pt)");
    config.samples = 1;
  }
  // Each hypothesis holds a TSDF, votes and labels over the scene grid, 20 bytes a voxel: those
  // of the widest grid must fit a machine's memory.
  const double gigabytes = 20e-9 * std::pow(widest, 3) * config.samples;
  if (gigabytes > kMaxHypothesesGB)
    throw std::invalid_argument(
        "samples " + std::to_string(config.samples) + " and workspace.max_tiles " +
        std::to_string(config.workspace.max_tiles) +
        ": the hypotheses over the widest scene grid (" + std::to_string(widest) +
        "^3 voxels) would take " + std::to_string(gigabytes).substr(0, 4) + " GB, over " +
        std::to_string(static_cast<int>(kMaxHypothesesGB)) + "; lower one of them");
  return config;
}

}  // namespace

ScenePerception::ScenePerception(const PerceptionConfig& config) : impl_(new Impl) {
  // The ranges before the slow model load, then what the model needs.
  validatePerceptionConfig(config, false);
  impl_->model = std::make_unique<CvaeInference>(config.model_path, cappedThreads(config.threads));
  validatePerceptionConfig(config, impl_->model->config().hasLatentCode());
  impl_->config = forModel(config, impl_->model->config());
  impl_->model_path = impl_->config.model_path;
  impl_->threads = impl_->config.threads;
}

PerceptionConfig ScenePerception::settingsInEffect(const PerceptionConfig& config) const {
  if (config.model_path != impl_->model_path)
    throw std::invalid_argument("updateSettings keeps the model: " + impl_->model_path + ", not " +
                                config.model_path);
  if (cappedThreads(config.threads) != impl_->threads)
    throw std::invalid_argument("updateSettings keeps the thread count");
  const bool latent = impl_->model->config().hasLatentCode();
  PerceptionConfig c = config;
  // Fewer samples than hypotheses to decompose decompose them all, rather than being refused:
  // samples is the setting an operator lowers to speed a frame up.
  if (latent) c.decompose_samples = std::min(c.decompose_samples, c.samples);
  // A change is judged as itself, not as the file the first settings came from.
  PerceptionConfig change = c;
  change.source.clear();
  validatePerceptionConfig(change, latent);
  return forModel(c, impl_->model->config());
}

void ScenePerception::updateSettings(const PerceptionConfig& config) {
  const PerceptionConfig in_effect = settingsInEffect(config);
  std::lock_guard<std::mutex> lock(impl_->mutex);
  impl_->config = in_effect;
}

ScenePerception::~ScenePerception() = default;
const PerceptionConfig& ScenePerception::config() const { return impl_->config; }
const CvaeConfig& ScenePerception::modelConfig() const { return impl_->model->config(); }

namespace {

/// The table frame of the first view: its pose, or a RANSAC plane.
Transform firstViewPose(const DepthView& view, const PerceptionConfig& c, bool* estimated) {
  *estimated = !view.T_table_camera;
  if (view.T_table_camera) return *view.T_table_camera;
  return estimateTablePlane(view.depth, view.camera, c.table, c.workspace).T_table_camera;
}

/// The partial TSDF and weight over `grid` of views [begin, end) (the first view posed by
/// `T_table_first`, the others by their own poses).
std::pair<Grid3<float>, Grid3<float>> partialTsdf(const GridSpec& grid,
                                                  const std::vector<DepthView>& views,
                                                  const Transform& T_table_first,
                                                  double truncation_m, size_t begin, size_t end) {
  ProjectiveTsdfConfig tc;
  tc.truncation_m = truncation_m;
  ProjectiveTsdf partial(grid, tc);
  for (size_t i = begin; i < end; ++i)
    partial.integrate(views[i].depth, views[i].camera,
                      i == 0 ? T_table_first : *views[i].T_table_camera);
  return {partial.tsdf(), partial.weight()};
}

/// How many of the views, from the first, the network is conditioned on
/// (PerceptionConfig::condition_views).
size_t conditioningViews(const std::vector<DepthView>& views, const PerceptionConfig& c) {
  return c.condition_views == "first" ? 1 : views.size();
}

/// Whether the codes are chosen or fitted by the views (CvaeInference::refine).
bool refinesCodes(const std::vector<DepthView>& views, const PerceptionConfig& c) {
  return views.size() > 1 && (c.refine_iterations > 0 || c.refine_starts > c.samples);
}

/// Whether views after the first reach the hypotheses, by conditioning or the codes.
bool furtherViewsReach(const std::vector<DepthView>& views, const PerceptionConfig& c) {
  return conditioningViews(views, c) > 1 || refinesCodes(views, c);
}

/// The network's S hypotheses for one tile from its partial TSDF; with several views and
/// `refine_iterations`, their codes fitted to each view's own partial TSDF.
std::vector<CvaePrediction> predictTile(const CvaeInference& model,
                                        const std::pair<Grid3<float>, Grid3<float>>& partial,
                                        const std::vector<DepthView>& views,
                                        const Transform& T_table_first, const PerceptionConfig& c) {
  if (!refinesCodes(views, c))
    return model.predict(partial.first, partial.second, c.samples, c.seed, c.zero_code_first,
                         c.symmetries);
  std::vector<ViewEvidence> evidence;
  for (size_t i = 0; i < views.size(); ++i) {
    auto [tsdf, weight] = partialTsdf(partial.first.spec, views, T_table_first,
                                      truncationIn(model.config(), partial.first.spec), i, i + 1);
    evidence.push_back({std::move(tsdf), std::move(weight)});
  }
  return model.refine(partial.first, partial.second, evidence, c.samples, c.seed, c.zero_code_first,
                      refineOptions(c));
}

/// The network's S hypotheses over one group's grid: each tile predicted from its own partial
/// TSDF, then the tiles blended (workspace.h).
std::vector<SceneHypothesis> predictGroup(
    const CvaeInference& model, const TileGroup& group, const std::vector<DepthView>& views,
    const Transform& T_table_first, const std::pair<Grid3<float>, Grid3<float>>& scene_partial,
    const PerceptionConfig& c) {
  const double truncation = truncationIn(model.config(), group.grid);
  std::vector<std::vector<CvaePrediction>> tiles;
  for (const GridSpec& tile : group.tiles) {
    if (tile == scene_partial.first.spec) {  // the common case: computed already
      tiles.push_back(predictTile(model, scene_partial, views, T_table_first, c));
      continue;
    }
    tiles.push_back(predictTile(
        model, partialTsdf(tile, views, T_table_first, truncation, 0, conditioningViews(views, c)),
        views, T_table_first, c));
  }
  std::vector<SceneHypothesis> out(tiles.front().size());
  for (size_t k = 0; k < out.size(); ++k) {
    std::vector<Grid3<float>> tsdf;
    std::vector<Grid3<Vec3f>> votes;
    for (auto& tile : tiles) {
      tsdf.push_back(std::move(tile[k].tsdf_m));
      votes.push_back(std::move(tile[k].votes));
    }
    out[k].tsdf_m = blendTiles(group.grid, tsdf, static_cast<float>(truncation));
    out[k].votes = blendTiles(group.grid, votes, Vec3f(Vec3f::Zero()));
    out[k].labels = Grid3<int>(group.grid, -1);
  }
  return out;
}

/// One group of tiles seen as a scene of its own: predicted, and the first hypotheses
/// decomposed on the group's grid (`held` as decompose takes it).
std::vector<SceneHypothesis> perceiveGroup(
    const CvaeInference& model, const TileGroup& group, const std::vector<DepthView>& views,
    const Transform& T_table_first, const std::pair<Grid3<float>, Grid3<float>>& scene_partial,
    const PerceptionConfig& c, const std::vector<Points3>& held, StageTimings* timings) {
  auto t = Clock::now();
  std::vector<SceneHypothesis> hypotheses =
      predictGroup(model, group, views, T_table_first, scene_partial, c);
  timings->network_ms += msSince(t);
  std::optional<SurfaceSegments> segments;
  if (c.segments.enabled && c.decompose_samples > 0) {
    t = Clock::now();
    segments = InstanceFinder(c.hough, c.segments)
                   .segmentView(views[0].depth, views[0].camera, T_table_first, c.min_pile_height_m,
                                &group.grid);
    timings->instances_ms += msSince(t);
  }
  // The patches are the first view's: when more views reach the hypotheses (conditioning or
  // code fitting), an instance it misses may be seen by another, so none is joined for being
  // unseen.
  PerceptionConfig one_view = c;
  if (furtherViewsReach(views, c)) one_view.segments.max_unseen_points = 0;
  // Every posed view measured part of the surface, whether or not it conditions the network;
  // the first view's points are the patches' when they were found.
  std::vector<MeasuredView> measured;
  if (c.observed_points && c.decompose_samples > 0)
    for (size_t i = 0; i < views.size(); ++i)
      measured.push_back(i == 0 && segments
                             ? MeasuredView{views[0].camera, T_table_first, segments->points_table}
                             : measuredView(views[i],
                                            i == 0 ? T_table_first : *views[i].T_table_camera,
                                            group.grid, c));
  for (int k = 0; k < c.decompose_samples; ++k)
    decompose(&hypotheses[k], one_view, timings, segments ? &*segments : nullptr, measured, held);
  return hypotheses;
}

/// The groups' hypotheses joined on the scene grid: each voxel's TSDF and vote the weighted
/// mean of the groups' (trilinear; weights by groupWeight), its label the group's holding it
/// farthest in, and each group's instances that lie nearer its own points than any other
/// group's (a tile also sees the edge of a neighbouring group). The surface is made again
/// from the joined TSDF.
SceneHypothesis joinGroups(const TilePlan& plan, std::vector<SceneHypothesis>& parts,
                           float truncation) {
  SceneHypothesis h;
  h.labels = Grid3<int>(plan.scene, -1);
  // Each group's instances that are kept, and where: a group's label l becomes joined[g][l].
  std::vector<std::vector<int>> joined(parts.size());
  for (size_t g = 0; g < parts.size(); ++g) {
    h.decomposed = h.decomposed || parts[g].decomposed;
    for (InstanceEstimate& e : parts[g].instances) {
      joined[g].push_back(-1);
      if (plan.groupOf(e.vote_centre) != static_cast<int>(g)) continue;
      joined[g].back() = static_cast<int>(h.instances.size());
      h.instances.push_back(std::move(e));
    }
  }
  const auto weight = [&](size_t g, const Vec3& p) { return groupWeight(plan.groups[g], p); };
  std::vector<Grid3<float>> tsdf;
  std::vector<Grid3<Vec3f>> votes;
  for (const SceneHypothesis& part : parts) {
    tsdf.push_back(part.tsdf_m);
    votes.push_back(part.votes);
  }
  h.tsdf_m = blendGrids(plan.scene, tsdf, weight, truncation);
  h.votes = blendGrids(plan.scene, votes, weight, Vec3f(Vec3f::Zero()));
  // Each voxel takes the label of the group holding it farthest in; where that group's
  // instance there was left to another group (its centre lies in the other's part), the
  // label of the next group that holds a kept instance there.
  std::vector<std::pair<double, size_t>> by_weight;
  for (int i = 0; i < plan.scene.voxelCount(); ++i) {
    const Vec3i v = plan.scene.unravel(i);
    const Vec3 p = plan.scene.voxelCentre(v.x(), v.y(), v.z());
    by_weight.clear();
    for (size_t g = 0; g < parts.size(); ++g)
      if (const double w = weight(g, p); w > 0.0) by_weight.emplace_back(w, g);
    std::sort(by_weight.begin(), by_weight.end(),
              [](const auto& a, const auto& b) { return a.first > b.first; });
    for (const auto& [w, g] : by_weight) {
      const Vec3i j = parts[g].labels.spec.voxelIndex(p);
      if (!parts[g].labels.spec.inside(j.x(), j.y(), j.z())) continue;
      const int l = parts[g].labels.at(j.x(), j.y(), j.z());
      if (l < 0 || l >= static_cast<int>(joined[g].size())) break;  // free space there
      if (joined[g][l] < 0) continue;  // an instance kept by another group
      h.labels.data[i] = joined[g][l];
      break;
    }
  }
  if (h.decomposed) h.surface = extractSurface(h.tsdf_m);
  return h;
}

/// Where the grid goes when nothing stands on the table: on the table the camera sees (the
/// median of its points), so that the network is shown seen free space. The camera's own
/// footprint, the fallback when not even the table is seen, leaves most of the grid unseen.
Vec2 bareTableCentre(const DepthView& view, const Transform& T_table_camera,
                     const PerceptionConfig& c) {
  const std::vector<Vec3> table =
      pilePoints(view, T_table_camera, c.workspace, -std::numeric_limits<double>::infinity(),
                 c.min_pile_height_m);
  return table.empty() ? Vec2(T_table_camera.translation().head<2>()) : medianXY(table);
}

}  // namespace

void checkPerceivableView(const DepthView& view, const PerceptionConfig& config) {
  checkView(view, 0);
  withinSensorRange({view}, config);
}

namespace {

/// The cube roots of the voxels of `instances`, ascending: how large the objects look to the
/// network.
std::vector<double> objectVoxels(const std::vector<InstanceEstimate>& instances) {
  std::vector<double> sizes;
  for (const InstanceEstimate& e : instances)
    if (e.voxels > 0) sizes.push_back(std::cbrt(static_cast<double>(e.voxels)));
  std::sort(sizes.begin(), sizes.end());
  return sizes;
}

}  // namespace

double gridSideFor(const GridConfig& grid, double side_m, double object_voxels,
                   double smallest_voxels) {
  if (grid.object_voxels <= 0.0 || object_voxels <= 0.0) return side_m;
  const bool small = object_voxels < grid.object_voxels ||
                     (smallest_voxels > 0.0 && smallest_voxels < grid.smallest_object_voxels);
  return small ? grid.fine_side_share * side_m : side_m;
}

SceneEstimate ScenePerception::perceive(const std::vector<DepthView>& views_given) const {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  const PerceptionConfig& c = impl_->config;
  if (views_given.empty()) throw std::invalid_argument("perceive: no depth view given");
  for (size_t i = 0; i < views_given.size(); ++i) {
    checkView(views_given[i], i);
    // Several views are fused in the frame their poses share, which RANSAC cannot give.
    if (views_given.size() > 1 && !views_given[i].T_table_camera)
      throw std::invalid_argument("perceive: view " + std::to_string(i) + " of " +
                                  std::to_string(views_given.size()) +
                                  " has no pose; only a single view may leave the table to RANSAC");
  }
  std::vector<DepthView> views = withinSensorRange(views_given, c);
  const auto start = Clock::now();
  SceneEstimate out;
  auto t = Clock::now();
  out.T_table_camera = firstViewPose(views[0], c, &out.table_estimated);
  for (size_t i = 0; i < views.size(); ++i)
    cropToWorkspace(&views[i], i == 0 ? out.T_table_camera : *views[i].T_table_camera, c.workspace);
  out.timings.table_ms = msSince(t);

  const double model_side = impl_->model->config().extent_m;
  const double first_side = c.grid.side_m > 0.0 ? c.grid.side_m : model_side;
  const PerceptionConfig first_config = scaledToSide(c, first_side, model_side);
  const TilePlan first_plan = planGrid(views[0], out.T_table_camera, first_side, first_config);
  perceiveInGrid(views, views_given, first_plan, first_side, first_config, {}, &out);
  const std::vector<double> sizes = objectVoxels(out.instances());
  if (!sizes.empty()) {
    out.object_voxels = sizes[sizes.size() / 2];
    out.smallest_object_voxels = sizes.front();
  }
  // Without the regrouping along the observed surface the finer grid's fragments stay apart
  // (two 3-object piles: 66 and 125 instances), so the first pass stands.
  const double side = c.segments.enabled ? gridSideFor(c.grid, first_side, out.object_voxels,
                                                       out.smallest_object_voxels)
                                         : first_side;
  if (side != first_side) {
    // The objects look small to the network: the frame again, in a finer grid, unless its
    // tiles would leave out part of the pile the first held (workspace.max_tiles, or a pile
    // taller than the finer grid). What the first pass found is dropped, but for its objects'
    // depth points; its time and tiles are counted.
    const PerceptionConfig fine_config = scaledToSide(c, side, model_side);
    const TilePlan fine_plan = planGrid(views[0], out.T_table_camera, side, fine_config);
    const auto leftOut = [&](const TilePlan& plan) {
      return outsideTiles(views[0], out.T_table_camera, plan, c.min_pile_height_m).size();
    };
    if (!(fine_plan.cropped && !first_plan.cropped) && leftOut(fine_plan) <= leftOut(first_plan)) {
      SceneEstimate finer;
      finer.T_table_camera = out.T_table_camera;
      finer.table_estimated = out.table_estimated;
      finer.object_voxels = out.object_voxels;
      finer.smallest_object_voxels = out.smallest_object_voxels;
      finer.timings = out.timings;
      finer.tiles = out.tiles;
      // The first pass's objects vouch for a container's walls, and for an object's sides seen
      // past a nearer one, that the finer grid parts.
      std::vector<Points3> held;
      for (InstanceEstimate& e : out.hypotheses.front().instances)
        held.push_back(std::move(e.measured));
      out = SceneEstimate();  // its grids freed before the finer pass's are made
      perceiveInGrid(views, views_given, fine_plan, side, fine_config, held, &finer);
      out = std::move(finer);
    }
  }
  out.timings.total_ms = msSince(start);
  return out;
}

TilePlan ScenePerception::planGrid(const DepthView& view, const Transform& T_table_camera,
                                   double side_m, const PerceptionConfig& c) const {
  // Training's placement (visiblePileCentre near the median of the pile's points).
  const auto placement = [&](const Vec2& near) {
    return visiblePileCentre(view.depth, view.camera, T_table_camera, near, 0.5 * side_m,
                             c.min_pile_height_m);
  };
  const std::vector<Vec3> pile =
      pilePoints(view, T_table_camera, c.workspace, c.min_pile_height_m, side_m);
  const Vec2 centre =
      placement(pile.empty() ? bareTableCentre(view, T_table_camera, c) : medianXY(pile));
  return planTiles(pile, centre, placement, side_m, impl_->model->config().resolution, c.workspace);
}

void ScenePerception::perceiveInGrid(const std::vector<DepthView>& views,
                                     const std::vector<DepthView>& views_given,
                                     const TilePlan& plan, double side_m, const PerceptionConfig& c,
                                     const std::vector<Points3>& held,
                                     SceneEstimate* estimate) const {
  const CvaeConfig& mc = impl_->model->config();
  SceneEstimate& out = *estimate;
  const double tau = truncationIn(mc, plan.scene);
  out.tile_side_m = side_m;
  auto t = Clock::now();
  out.grid = plan.scene;
  out.tiles += plan.tileCount();
  out.tiles_cropped = plan.cropped;
  std::pair<Grid3<float>, Grid3<float>> partial =
      partialTsdf(out.grid, views, out.T_table_camera, tau, 0, conditioningViews(views, c));
  out.timings.tsdf_ms += msSince(t);

  // Each group as a scene of its own; one group is the scene.
  std::vector<std::vector<SceneHypothesis>> groups;
  for (const TileGroup& g : plan.groups)
    groups.push_back(
        perceiveGroup(*impl_->model, g, views, out.T_table_camera, partial, c, held, &out.timings));
  out.partial_tsdf_m = std::move(partial.first);
  out.partial_weight = std::move(partial.second);
  t = Clock::now();  // the groups' grids and instances joined: the instances' stage
  if (groups.size() == 1 && plan.groups.front().grid == plan.scene) {
    out.hypotheses = std::move(groups.front());
  } else {
    for (size_t k = 0; k < groups.front().size(); ++k) {
      std::vector<SceneHypothesis> parts;
      for (auto& g : groups) parts.push_back(std::move(g[k]));
      out.hypotheses.push_back(joinGroups(plan, parts, static_cast<float>(tau)));
    }
  }
  out.occupancy_probability = Grid3<float>(out.grid, 0.0f);
  for (const SceneHypothesis& h : out.hypotheses)
    for (size_t i = 0; i < h.tsdf_m.data.size(); ++i)
      if (h.tsdf_m.data[i] <= 0.0f)
        out.occupancy_probability.data[i] += 1.0f / out.hypotheses.size();
  out.timings.instances_ms += msSince(t);
  t = Clock::now();
  // The view as the truncation test reads it: without what the tiles left out (a copy only then).
  DepthView covered;
  const std::vector<int> outside =
      outsideTiles(views[0], out.T_table_camera, plan, c.min_pile_height_m);
  if (!outside.empty()) {
    covered = views[0];
    for (int i : outside) covered.depth.pixels[i] = 0.0f;
  }
  const DepthView& used = outside.empty() ? views[0] : covered;
  for (int k = 0; k < c.decompose_samples; ++k) {
    setVisibleFractions(&out.hypotheses[k], views[0].camera, out.T_table_camera);
    markTruncated(&out.hypotheses[k], views_given[0], used, out.T_table_camera,
                  c.min_pile_height_m);
  }
  out.timings.mesh_ms += msSince(t);
}

SceneEstimate ScenePerception::warmUp() const {
  // The box stands at the table's origin, or inside the workspace box where that leaves the
  // origin out (the middle of a bounded side, 10 cm in from a one-sided bound).
  const WorkspaceConfig w = config().workspace;
  Vec3 at(0.0, 0.0, 0.03);
  for (int i = 0; i < 2; ++i) {
    const bool lo = std::isfinite(w.min_m[i]), hi = std::isfinite(w.max_m[i]);
    if (lo && hi && !(w.min_m[i] <= 0.0 && 0.0 <= w.max_m[i]))
      at[i] = 0.5 * (w.min_m[i] + w.max_m[i]);
    else if (lo && !hi && w.min_m[i] > 0.0)
      at[i] = w.min_m[i] + 0.1;
    else if (hi && !lo && w.max_m[i] < 0.0)
      at[i] = w.max_m[i] - 0.1;
  }
  SuperquadricShape box;
  box.scale_m = Vec3(0.06, 0.04, 0.03);
  box.exponents = Vec3(10.0, 10.0, 10.0);
  box.T_table_object.translation() = at;
  const DepthRenderer renderer(Scene::fromSuperquadrics({box}));
  DepthView view;
  view.T_table_camera = lookAt(at + Vec3(0.45, -0.3, 0.52), at);
  view.depth = renderer.render(view.camera, *view.T_table_camera).depth;
  return perceive(view);
}

ModelSelfTest runModelSelfTest(const std::string& model_path) {
  PerceptionConfig config;
  config.model_path = model_path;
  config.samples = 1;
  config.symmetries = 1;
  // One box in one grid: no tiles, so no overlap to fit into a smaller model's grid (the
  // default overlap is half a 0.32 m grid).
  config.workspace.tile_overlap_m = 0.0;
  config.grid.object_voxels = 0.0;  // the card's figures are one pass's
  const SceneEstimate estimate = ScenePerception(config).warmUp();
  ModelSelfTest out;
  out.objects = static_cast<int>(estimate.instances().size());
  for (float p : estimate.occupancy_probability.data) out.occupied_voxels += p >= 0.5f;
  return out;
}

ModelSelfTest checkModel(const std::string& model_path) {
  const std::optional<ModelIntegrity> card = readModelIntegrity(model_path);
  const ModelSelfTest got = runModelSelfTest(model_path);  // loading verifies hash and weights
  if (!card || card->self_test_objects < 0) return got;
  const int want = card->self_test_occupied_voxels;
  const bool same = got.objects == card->self_test_objects &&
                    std::abs(got.occupied_voxels - want) <= std::max(5, want / 20);
  if (!same)
    throw std::runtime_error(
        "model " + model_path + " failed its self-test: on a rendered box its card " +
        modelCardPath(model_path) + " expects " + std::to_string(card->self_test_objects) +
        " object(s) and " + std::to_string(want) + " occupied voxels, it perceives " +
        std::to_string(got.objects) + " and " + std::to_string(got.occupied_voxels) +
        " (a damaged model, or not the one the card describes)");
  return got;
}

ModelIntegrity stampModel(const std::string& model_path) {
  requireModelNotCard(model_path);  // its own card would be written over it
  // The card keeps what it had until the model has loaded and passed its self-test: a damaged
  // or foreign file is not stamped as good.
  const std::string card = modelCardPath(model_path);
  if (std::filesystem::is_directory(card))
    throw std::runtime_error(card + " (the card of " + model_path + ") is a directory");
  std::optional<std::string> before;
  if (std::ifstream in{card, std::ios::binary})
    before = std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  ModelIntegrity m;
  m.sha256 = sha256OfFile(model_path);
  m.format_version = modelFormatVersion();
  try {
    writeModelIntegrity(model_path, m);  // the hash first: the self-test loads through its check
    const ModelSelfTest t = runModelSelfTest(model_path);
    m.self_test_objects = t.objects;
    m.self_test_occupied_voxels = t.occupied_voxels;
    writeModelIntegrity(model_path, m);
  } catch (...) {
    std::error_code ec;
    if (!before) {
      std::filesystem::remove(card, ec);
    } else {
      std::ofstream out(card, std::ios::binary | std::ios::trunc);
      out << *before;
    }
    throw;
  }
  return m;
}

}  // namespace simstack
