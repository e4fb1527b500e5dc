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
                             double max_height_m, int stride, std::vector<int>* pixels) {
  std::vector<Vec3> out;
  if (pixels) pixels->clear();
  const LatticeStart start = latticeStart(view.depth, stride);
  for (int v = start.v; v < view.depth.height; v += stride)
    for (int u = start.u; u < view.depth.width; u += stride) {
      const float d = view.depth.at(u, v);
      if (!validDepth(d)) continue;
      const Vec3 p = T_table_camera * view.camera.backproject(u, v, d);
      if (p.z() < min_height_m || p.z() > max_height_m || !workspace.contains(p)) continue;
      out.push_back(p);
      if (pixels) pixels->push_back(v * view.depth.width + u);
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
  std::array<std::vector<double>, 2> xy;  // its points' coordinates
  Vec2 lo, hi, median;                    // 0.5 / 99.5 percentiles and median (finish())

  void finish() {  // as medianXY and a single tile take them
    for (int a = 0; a < 2; ++a) {
      std::vector<double> x = xy[a];
      std::nth_element(x.begin(), x.begin() + x.size() / 2, x.end());
      median[a] = x[x.size() / 2];
      lo[a] = quantile(&x, 0.005);
      hi[a] = quantile(&x, 0.995);
    }
  }
  size_t size() const { return xy[0].size(); }
};

/// Connected groups of the points' x/y cells (side `cell`, 8-neighbourhood), with fewer than
/// `min_points` points dropped. The cells are hashed, not rasterised for OpenCV's labelling: a
/// flying pixel may lie as far as max_depth_m (up to 100 m), a raster of 10^7-10^8 cells.
std::vector<Cluster> connectedGroups(const std::vector<Vec3>& points, double cell,
                                     size_t min_points) {
  std::unordered_map<int64_t, std::vector<size_t>> cells;
  const auto key = [](int64_t i, int64_t j) {
    return static_cast<int64_t>((static_cast<uint64_t>(i) << 32) ^ static_cast<uint32_t>(j));
  };
  for (size_t k = 0; k < points.size(); ++k)
    cells[key(std::floor(points[k].x() / cell), std::floor(points[k].y() / cell))].push_back(k);
  std::unordered_map<int64_t, bool> seen;
  std::vector<Cluster> out;
  for (const auto& [start, unused] : cells) {
    if (seen[start]) continue;
    seen[start] = true;
    Cluster c;
    std::vector<int64_t> stack{start};
    while (!stack.empty()) {
      const int64_t k = stack.back();
      stack.pop_back();
      for (size_t i : cells.at(k))
        for (int a = 0; a < 2; ++a) c.xy[a].push_back(points[i][a]);
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
    if (c.size() >= min_points) out.push_back(std::move(c));
  }
  return out;
}

/// The connected groups, largest first, each joined with the smaller ones that fit one tile
/// (`side`, with `margin` on each side) together with it: a pile that one tile holds stays
/// one group, whatever gaps it has. Groups of fewer than 10 points left (flying pixels far from
/// everything) are dropped.
std::vector<Cluster> clusters(const std::vector<Vec3>& points, double cell, double side,
                              double margin) {
  std::vector<Cluster> parts = connectedGroups(points, cell, 1);
  for (Cluster& c : parts) c.finish();
  std::sort(parts.begin(), parts.end(),
            [](const Cluster& a, const Cluster& b) { return a.size() > b.size(); });
  std::vector<Cluster> out;
  std::vector<bool> used(parts.size(), false);
  for (size_t i = 0; i < parts.size(); ++i) {
    if (used[i]) continue;
    Cluster group = parts[i];
    for (size_t j = i + 1; j < parts.size(); ++j) {
      if (used[j]) continue;
      const Vec2 lo = group.lo.cwiseMin(parts[j].lo), hi = group.hi.cwiseMax(parts[j].hi);
      if ((hi - lo).maxCoeff() + 2.0 * margin > side) continue;
      for (int a = 0; a < 2; ++a)
        group.xy[a].insert(group.xy[a].end(), parts[j].xy[a].begin(), parts[j].xy[a].end());
      group.finish();
      used[j] = true;
    }
    if (group.size() >= 10) out.push_back(std::move(group));  // not a few flying pixels
  }
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
      origins[a].push_back(std::min(std::max(placement[a] - 0.5 * side, hi - side), lo));
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

/// The nearest point of the table frame's voxel lattice (x/y multiples of `voxel`).
Vec2 onLattice(const Vec2& p, double voxel) { return (p / voxel).array().round().matrix() * voxel; }

/// The group of tiles at these origins on the table frame's voxel lattice (the first moved by
/// up to half a voxel, the others keeping their spacing to it rounded: less than a voxel),
/// and the cube holding them on that lattice.
TileGroup tileGroup(std::vector<Vec2> origins, double voxel, int resolution) {
  TileGroup g;
  const Vec2 front = origins.front(), anchor = onLattice(front, voxel);
  Vec2 first = anchor, last = anchor;
  for (Vec2& o : origins) {
    o = anchor + ((o - front) / voxel).array().round().matrix() * voxel;
    first = first.cwiseMin(o);
    last = last.cwiseMax(o);
  }
  for (const Vec2& o : origins) {
    GridSpec t;
    t.origin_table = Vec3(o.x(), o.y(), 0.0);
    t.voxel_size_m = voxel;
    t.resolution = resolution;
    g.tiles.push_back(t);
  }
  g.grid = g.tiles.front();
  g.grid.origin_table.head<2>() = first;
  g.grid.resolution = resolution + static_cast<int>(std::lround((last - first).maxCoeff() / voxel));
  return g;
}

/// The tile origins nearest `middle` that fit, at most `count` of them, in a square of side
/// `max_side` (tiles of side `extent_m`).
std::vector<Vec2> nearestTiles(std::vector<Vec2> origins, const Vec2& middle, double extent_m,
                               double max_side, size_t count) {
  const Vec2 half = Vec2::Constant(0.5 * extent_m);
  std::sort(origins.begin(), origins.end(), [&](const Vec2& a, const Vec2& b) {
    return (a + half - middle).norm() < (b + half - middle).norm();
  });
  std::vector<Vec2> kept;
  Vec2 lo = Vec2::Constant(1e300), hi = Vec2::Constant(-1e300);
  for (const Vec2& o : origins) {
    const Vec2 l = lo.cwiseMin(o), h = hi.cwiseMax(o + Vec2::Constant(extent_m));
    if (kept.size() == count || (h - l).maxCoeff() > max_side + 1e-9) continue;
    lo = l;
    hi = h;
    kept.push_back(o);
  }
  return kept;
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
  const auto single = [&]() {
    // One tile: the training placement, moved just enough to hold the pile's spread.
    Vec2 centre = single_centre;
    for (int a = 0; a < 2; ++a)
      centre[a] = std::min(std::max(centre[a], hi[a] - 0.5 * extent_m), lo[a] + 0.5 * extent_m);
    plan.scene = GridSpec::sceneGrid(centre, extent_m, resolution);
    plan.scene.origin_table.head<2>() = onLattice(plan.scene.origin_table.head<2>(), voxel);
    TileGroup g;
    g.grid = plan.scene;
    g.tiles.push_back(plan.scene);
    g.lo = lo;
    g.hi = hi;
    plan.groups.push_back(g);
    return plan;
  };
  if ((hi - lo).maxCoeff() <= extent_m) return single();
  const std::vector<Cluster> groups = clusters(pile_points, margin, extent_m, margin);
  if (groups.empty()) return single();  // a few flying pixels far apart
  // Each separate group of the pile gets its own tiles, the largest groups first, as long as
  // the scene stays within a square of max_side (the tiles' count allows no wider).
  const double max_side = std::ceil(std::sqrt(workspace.max_tiles)) * extent_m;
  Vec2 scene_lo = Vec2::Constant(1e300), scene_hi = Vec2::Constant(-1e300);
  size_t tiles = 0;
  for (const Cluster& c : groups) {
    std::vector<Vec2> origins = clusterTiles(c, placement(c.median), voxel, resolution, overlap);
    Vec2 lo_c = scene_lo, hi_c = scene_hi;
    for (const Vec2& o : origins) {
      lo_c = lo_c.cwiseMin(o);
      hi_c = hi_c.cwiseMax(o + Vec2::Constant(extent_m));
    }
    const bool too_wide = (hi_c - lo_c).maxCoeff() > max_side + 1e-9;
    const bool too_many = tiles + origins.size() > static_cast<size_t>(workspace.max_tiles);
    if (tiles > 0 && (too_wide || too_many)) {
      plan.cropped = true;
      if (too_wide) continue;
      break;
    }
    if (too_wide || too_many) {
      // Even the largest group needs more, or a row longer than the square: its tiles
      // nearest its middle.
      plan.cropped = true;
      origins = nearestTiles(origins, 0.5 * (c.lo + c.hi), extent_m, max_side,
                             static_cast<size_t>(workspace.max_tiles));
    }
    tiles += origins.size();
    for (const Vec2& o : origins) {
      scene_lo = scene_lo.cwiseMin(o);
      scene_hi = scene_hi.cwiseMax(o + Vec2::Constant(extent_m));
    }
    plan.groups.push_back(tileGroup(origins, voxel, resolution));
    plan.groups.back().lo = c.lo;
    plan.groups.back().hi = c.hi;
  }
  // The scene cube, holding every group, on the lattice they share.
  Vec2 first = plan.groups.front().grid.origin_table.head<2>(), last = first;
  for (const TileGroup& g : plan.groups) {
    const Vec2 o = g.grid.origin_table.head<2>();
    first = first.cwiseMin(onLattice(o, voxel));
    last = last.cwiseMax(o + Vec2::Constant(g.grid.extent_m()));
  }
  const int n = static_cast<int>(std::ceil((last - first).maxCoeff() / voxel - 1e-6));
  plan.scene.origin_table = Vec3(first.x(), first.y(), 0.0);
  plan.scene.voxel_size_m = voxel;
  plan.scene.resolution = std::max(n, resolution);
  return plan;
}

double tileWeight(const GridSpec& tile, const Vec3& p) {
  const Vec3 c = tile.continuousIndex(p);
  const double r = tile.resolution;
  if ((c.array() < -0.5).any() || (c.array() > r - 0.5).any()) return 0.0;
  return 1e-3 +
         std::min(std::min(c.x() + 0.5, r - 0.5 - c.x()), std::min(c.y() + 0.5, r - 0.5 - c.y()));
}

double groupWeight(const TileGroup& group, const Vec3& p) {
  double best = 0.0;
  for (const GridSpec& t : group.tiles) best = std::max(best, tileWeight(t, p));
  return best;
}

Vec2 medianXY(std::vector<Vec3> points) {
  Vec2 out;
  for (int a = 0; a < 2; ++a) {
    std::nth_element(points.begin(), points.begin() + points.size() / 2, points.end(),
                     [a](const Vec3& l, const Vec3& r) { return l[a] < r[a]; });
    out[a] = points[points.size() / 2][a];
  }
  return out;
}

int TilePlan::tileCount() const {
  int n = 0;
  for (const TileGroup& g : groups) n += static_cast<int>(g.tiles.size());
  return n;
}

int TilePlan::groupOf(const Vec3& p_table) const {
  int best = 0;
  double best_d = std::numeric_limits<double>::infinity();
  for (size_t k = 0; k < groups.size(); ++k) {
    const Vec2 q = p_table.head<2>();
    const double d = (q - q.cwiseMax(groups[k].lo).cwiseMin(groups[k].hi)).norm();
    if (d < best_d) best_d = d, best = static_cast<int>(k);
  }
  return best;
}

}  // namespace simstack
