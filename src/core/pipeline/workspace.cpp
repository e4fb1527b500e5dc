#include "simstack/pipeline/workspace.h"

#include <cmath>
#include <stdexcept>
#include <string>
#include <unordered_map>

namespace simstack {

bool WorkspaceConfig::bounded() const {
  for (int i = 0; i < 3; ++i)
    if (std::isfinite(min_m[i]) || std::isfinite(max_m[i])) return true;
  return false;
}

bool WorkspaceConfig::contains(const Vec3& p) const {
  for (int i = 0; i < 3; ++i)
    if (!(p[i] >= min_m[i] && p[i] <= max_m[i])) return false;
  return true;
}

void WorkspaceConfig::validate() const {
  static const char* axis = "xyz";
  for (int i = 0; i < 3; ++i)
    if (std::isnan(min_m[i]) || std::isnan(max_m[i]) || !(min_m[i] < max_m[i]))
      throw std::invalid_argument(std::string("workspace: min_m.") + axis[i] + " (" +
                                  std::to_string(min_m[i]) + ") must be below max_m." + axis[i] +
                                  " (" + std::to_string(max_m[i]) + ")");
  if (max_tiles < 1 || max_tiles > 64)
    throw std::invalid_argument("workspace: max_tiles must lie in [1, 64], not " +
                                std::to_string(max_tiles));
  if (!(tile_overlap_m >= 0.0))
    throw std::invalid_argument("workspace: tile_overlap_m must be >= 0, not " +
                                std::to_string(tile_overlap_m));
}

std::vector<Vec3> pilePoints(const DepthView& view, const Transform& T_table_camera,
                             const WorkspaceConfig& workspace, double min_height_m,
                             double max_height_m, int stride) {
  std::vector<Vec3> out;
  for (int v = 0; v < view.depth.height; v += stride)
    for (int u = 0; u < view.depth.width; u += stride) {
      const float d = view.depth.at(u, v);
      if (!validDepth(d)) continue;
      const Vec3 p = T_table_camera * view.camera.backproject(u, v, d);
      if (p.z() < min_height_m || p.z() > max_height_m || !workspace.contains(p)) continue;
      out.push_back(p);
    }
  return out;
}

void applyMask(DepthView* view) {
  if (view->mask.empty()) return;
  for (size_t i = 0; i < view->depth.pixels.size(); ++i)
    if (view->mask.pixels[i] == 0) view->depth.pixels[i] = 0.0f;
}

void cropToWorkspace(DepthView* view, const Transform& T_table_camera,
                     const WorkspaceConfig& workspace) {
  if (!workspace.bounded()) return;
  DepthImage& depth = view->depth;
  for (int v = 0; v < depth.height; ++v)
    for (int u = 0; u < depth.width; ++u) {
      float& d = depth.at(u, v);
      if (validDepth(d) && !workspace.contains(T_table_camera * view->camera.backproject(u, v, d)))
        d = 0.0f;
    }
}

namespace {

/// The q-quantile of the values (q in [0, 1]); reorders them.
double quantile(std::vector<double>* values, double q) {
  const size_t k = std::min(values->size() - 1, static_cast<size_t>(q * (values->size() - 1)));
  std::nth_element(values->begin(), values->begin() + k, values->end());
  return (*values)[k];
}

/// A group of pile points separated from the others by at least two voxels of nothing.
struct Cluster {
  Vec2 lo, hi, median;
  size_t points = 0;
};

/// Connected groups of the points' x/y cells (side `cell`, 8-neighbourhood), with fewer than
/// `min_points` points dropped (flying pixels), largest first.
std::vector<Cluster> clusters(const std::vector<Vec3>& points, double cell, size_t min_points) {
  std::unordered_map<int64_t, std::vector<size_t>> cells;
  const auto key = [](int64_t i, int64_t j) { return (i << 32) ^ (j & 0xffffffff); };
  for (size_t k = 0; k < points.size(); ++k)
    cells[key(std::floor(points[k].x() / cell), std::floor(points[k].y() / cell))].push_back(k);
  std::unordered_map<int64_t, bool> seen;
  std::vector<Cluster> out;
  for (const auto& [start, unused] : cells) {
    if (seen[start]) continue;
    seen[start] = true;
    Cluster c;
    c.lo = Vec2::Constant(1e300);
    c.hi = Vec2::Constant(-1e300);
    std::array<std::vector<double>, 2> coordinates;
    std::vector<int64_t> stack{start};
    while (!stack.empty()) {
      const int64_t k = stack.back();
      stack.pop_back();
      for (size_t i : cells.at(k)) {
        const Vec2 p = points[i].head<2>();
        c.lo = c.lo.cwiseMin(p);
        c.hi = c.hi.cwiseMax(p);
        coordinates[0].push_back(p.x());
        coordinates[1].push_back(p.y());
        ++c.points;
      }
      const Vec3& any = points[cells.at(k).front()];
      const int64_t ci = std::floor(any.x() / cell), cj = std::floor(any.y() / cell);
      for (int64_t di = -1; di <= 1; ++di)
        for (int64_t dj = -1; dj <= 1; ++dj) {
          const int64_t n = key(ci + di, cj + dj);
          if (cells.count(n) && !seen[n]) {
            seen[n] = true;
            stack.push_back(n);
          }
        }
    }
    if (c.points < min_points) continue;
    for (int a = 0; a < 2; ++a) {  // as observedPileCentre takes it
      std::vector<double>& x = coordinates[a];
      std::nth_element(x.begin(), x.begin() + x.size() / 2, x.end());
      c.median[a] = x[x.size() / 2];
    }
    out.push_back(c);
  }
  std::sort(out.begin(), out.end(),
            [](const Cluster& a, const Cluster& b) { return a.points > b.points; });
  return out;
}

/// Tile origins (x/y, metres, before they are put on one voxel lattice) covering one cluster:
/// one tile at the training placement when it fits, else the fewest evenly spread tiles that
/// overlap by at least `overlap` voxels.
std::vector<Vec2> clusterTiles(const Cluster& c, const Vec2& placement, double voxel, int r,
                               int overlap) {
  const double margin = 2.0 * voxel, side = r * voxel;
  std::array<std::vector<double>, 2> origins;
  for (int a = 0; a < 2; ++a) {
    const double lo = c.lo[a] - margin, hi = c.hi[a] + margin;
    const int span = static_cast<int>(std::ceil((hi - lo) / voxel - 1e-9));
    if (span <= r) {
      origins[a].push_back(std::clamp(placement[a] - 0.5 * side, hi - side, lo));
      continue;
    }
    const int count = 1 + (span - overlap - 1) / (r - overlap);
    for (int k = 0; k < count; ++k) origins[a].push_back(lo + k * (hi - lo - side) / (count - 1));
  }
  std::vector<Vec2> out;
  for (double y : origins[1])
    for (double x : origins[0]) out.emplace_back(x, y);
  return out;
}

}  // namespace

TilePlan planTiles(const std::vector<Vec3>& pile_points, const Vec2& single_centre,
                   const std::function<Vec2(const Vec2&)>& placement, double extent_m,
                   int resolution, const WorkspaceConfig& workspace) {
  workspace.validate();
  const double voxel = extent_m / resolution;
  const int overlap = static_cast<int>(std::ceil(workspace.tile_overlap_m / voxel - 1e-9));
  if (overlap >= resolution / 2)
    throw std::invalid_argument(
        "workspace: tile_overlap_m (" + std::to_string(workspace.tile_overlap_m) +
        " m) must be less than half a tile's side (" + std::to_string(0.5 * extent_m) + " m)");
  TilePlan plan;
  const double margin = 2.0 * voxel;
  Vec2 lo = single_centre, hi = single_centre;
  if (!pile_points.empty()) {
    for (int a = 0; a < 2; ++a) {
      std::vector<double> c;
      c.reserve(pile_points.size());
      for (const Vec3& p : pile_points) c.push_back(p[a]);
      lo[a] = quantile(&c, 0.005) - margin;
      hi[a] = quantile(&c, 0.995) + margin;
    }
  }
  if ((hi - lo).maxCoeff() <= extent_m) {
    // One tile: the training placement, moved just enough to hold the pile's spread.
    Vec2 centre = single_centre;
    for (int a = 0; a < 2; ++a)
      centre[a] = std::clamp(centre[a], hi[a] - 0.5 * extent_m, lo[a] + 0.5 * extent_m);
    plan.scene = GridSpec::sceneGrid(centre, extent_m, resolution);
    plan.tiles.push_back(plan.scene);
    return plan;
  }
  // Each separate group of the pile gets its own tiles, the largest groups first.
  std::vector<Vec2> origins;
  for (const Cluster& c : clusters(pile_points, margin, 10)) {
    const std::vector<Vec2> more = clusterTiles(c, placement(c.median), voxel, resolution, overlap);
    if (origins.size() + more.size() > static_cast<size_t>(workspace.max_tiles)) {
      plan.cropped = true;
      if (!origins.empty()) break;
      // Even the largest group needs more: its tiles nearest its middle.
      std::vector<Vec2> sorted = more;
      const Vec2 middle = 0.5 * (c.lo + c.hi);
      std::sort(sorted.begin(), sorted.end(), [&](const Vec2& a, const Vec2& b) {
        return (a - middle).norm() < (b - middle).norm();
      });
      sorted.resize(workspace.max_tiles);
      origins = sorted;
      break;
    }
    origins.insert(origins.end(), more.begin(), more.end());
  }
  // Every tile on the voxel lattice of the largest group's (first) tile, which is then placed
  // exactly as alone (resampling the others onto it cost more than moving them by up to half
  // a voxel); the scene cube from the tiles' lowest corner, as wide as their union.
  const Vec2 anchor = origins.front();
  for (Vec2& o : origins) o = anchor + ((o - anchor) / voxel).array().round().matrix() * voxel;
  Vec2 first = anchor, last = anchor;
  for (const Vec2& o : origins) {
    first = first.cwiseMin(o);
    last = last.cwiseMax(o);
  }
  const int n = static_cast<int>(std::lround((last - first).maxCoeff() / voxel)) + resolution;
  plan.scene.origin_table = Vec3(first.x(), first.y(), 0.0);
  plan.scene.voxel_size_m = voxel;
  plan.scene.resolution = n;
  for (const Vec2& o : origins) {
    GridSpec t;
    t.origin_table = Vec3(o.x(), o.y(), 0.0);
    t.voxel_size_m = voxel;
    t.resolution = resolution;
    plan.tiles.push_back(t);
  }
  return plan;
}

}  // namespace simstack
