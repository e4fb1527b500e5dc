#include "simstack/instances/hough_voting.h"

#include "simstack/assert.h"

#include <omp.h>

#include <nanoflann.hpp>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <limits>
#include <map>
#include <memory>
#include <numeric>
#include <sstream>
#include <stdexcept>
#include <string>

namespace simstack {
namespace {

/// Where a fine coordinate along one axis puts a cell: its voxel's offset in the scene grid's
/// linear index (high 32 bits) and its offset inside the voxel's ref^3 block (low 32 bits).
/// The three axes' entries of a cell add up to both indices at once (no field overflows).
std::vector<uint64_t> fineAxisTable(int r, int ref, int axis) {
  const uint64_t voxel_stride = axis == 0 ? 1 : axis == 1 ? r : uint64_t(r) * r;
  const uint64_t local_stride = axis == 0 ? 1 : axis == 1 ? ref : uint64_t(ref) * ref;
  std::vector<uint64_t> table(static_cast<size_t>(r) * ref);
  for (int c = 0; c < r * ref; ++c)
    table[c] = (c / ref) * voxel_stride << 32 | (c % ref) * local_stride;
  return table;
}

/// Marches the ray from fine-grid point `p` along `unit`, counting every fine cell it crosses
/// while it stays in (or within `tolerance` voxels of) occupied space. `block(scene voxel)`
/// gives that voxel's ref^3 fine counts (nullptr: not counted); each fine cell crossed bumps
/// its count, saturating. `axis_tables` are fineAxisTable() of x, y and z. Returns the fine
/// cells visited.
///
/// The ray is walked one slab of its major axis (largest |d|) at a time: along it every step
/// moves one cell, and the two minor coordinates move by at most one cell per slab; when both
/// do, the one that crosses first is visited first. These are the cells, in their order, of
/// Amanatides & Woo's cell-by-cell traversal (a test compares the counts with one), with two
/// independent additions per slab as the chain from one step to the next instead of a
/// comparison, a select and an addition per cell (docs/benchmarks.md).
template <class Count, class Block>
size_t marchRay(const Vec3& p, const Vec3& unit, int ref, const std::vector<uint8_t>& occ, int r,
                int tolerance, const std::vector<uint64_t>* axis_tables, Block&& block_of) {
  // Components within 1e-12 of zero do not move the ray (as in the cell-by-cell traversal).
  const Vec3 d = unit.unaryExpr([](double c) { return std::abs(c) > 1e-12 ? c : 0.0; });
  int m = 0;
  for (int a = 1; a < 3; ++a)
    if (std::abs(d[a]) > std::abs(d[m])) m = a;
  const int u_axis = m == 0 ? 1 : 0, w_axis = m == 2 ? 1 : 2;  // u before w in axis order
  const uint64_t* const tm = axis_tables[m].data();
  const uint64_t* const tu = axis_tables[u_axis].data();
  const uint64_t* const tw = axis_tables[w_axis].data();
  const unsigned fine = static_cast<unsigned>(r * ref);
  size_t visits = 0;
  int outside = 0;
  uint32_t current = ~0u;
  Count* block = nullptr;
  // The cell (major, u, w), inside the grid: false when the ray stops before it.
  auto visit = [&](int cm, int cu, int cw) {
    const uint64_t key = tm[cm] + tu[cu] + tw[cw];
    const uint32_t index = static_cast<uint32_t>(key >> 32);
    if (index != current) {  // entering a scene voxel
      current = index;
      outside = occ[index] ? 0 : outside + 1;
      if (outside > tolerance) return false;
      block = block_of(static_cast<int>(index));
    }
    ++visits;
    if (block) {
      Count& c = block[static_cast<uint32_t>(key)];
      c += c != std::numeric_limits<Count>::max();
    }
    return true;
  };
  // The ray leaves the grid where a coordinate leaves [0, fine): checked where one changes.
  auto inside = [fine](int c) { return static_cast<unsigned>(c) < fine; };
  const int sm = d[m] > 0 ? 1 : -1;
  const double ru = d[u_axis] / std::abs(d[m]), rw = d[w_axis] / std::abs(d[m]);
  const double aru = std::abs(ru), arw = std::abs(rw);
  // floor() of coordinates above -2^20 by truncation (no SSE4.1 round in the baseline ISA).
  auto floorInt = [](double x) { return static_cast<int>(x + (1 << 20)) - (1 << 20); };
  int cm = floorInt(p[m]);
  double u = p[u_axis], w = p[w_axis];
  int cu = floorInt(u), cw = floorInt(w);
  // A ray that starts on a cell boundary and moves down across it (an even refinement starts
  // every ray on a cell corner) enters the cell below at once, as in Amanatides & Woo: one axis
  // after the other, the later axis first, each cell on the way visited.
  for (int a = 2; a >= 0; --a) {
    if (!(d[a] < 0 && p[a] == std::floor(p[a]))) continue;
    if (!inside(cm) || !inside(cu) || !inside(cw) || !visit(cm, cu, cw)) return visits;
    --(a == m ? cm : a == u_axis ? cu : cw);
  }
  if (!inside(cu) || !inside(cw)) return visits;
  // The first slab runs from p to the next boundary of the major axis, the others are whole.
  const double first = sm > 0 ? cm + 1 - p[m] : p[m] - cm;
  double step_u = ru * first, step_w = rw * first;
  while (inside(cm) && visit(cm, cu, cw)) {
    const double u1 = u + step_u, w1 = w + step_w;
    const int cu1 = floorInt(u1), cw1 = floorInt(w1);
    if (cu1 != cu) {
      if (cw1 != cw) {
        // Both minor coordinates change: the one whose boundary comes first (in major-axis
        // travel: distance to the boundary over the rate) goes first; ties to the later axis.
        const double to_u = (ru > 0 ? cu + 1 - u : u - cu) * arw;
        const double to_w = (rw > 0 ? cw + 1 - w : w - cw) * aru;
        if (!(to_u < to_w ? inside(cu1) && visit(cm, cu1, cw) : inside(cw1) && visit(cm, cu, cw1)))
          break;
        if (!inside(cu1) || !inside(cw1) || !visit(cm, cu1, cw1)) break;
      } else if (!inside(cu1) || !visit(cm, cu1, cw)) {
        break;
      }
    } else if (cw1 != cw && (!inside(cw1) || !visit(cm, cu, cw1))) {
      break;
    }
    cm += sm;
    u = u1;
    w = w1;
    cu = cu1;
    cw = cw1;
    step_u = ru;
    step_w = rw;
  }
  return visits;
}

/// A mean-shift point: a voxel's count-weighted mean position `p` (table frame), its weight
/// `w` (the counts), and for exact window sums its position times its weight in integers, in
/// half fine cells from the grid's origin (p = origin + h / 2 * q / w).
struct WeightedPoint {
  Vec3 p = Vec3::Zero();
  int64_t w = 0;
  int64_t q[3] = {0, 0, 0};
};

struct WeightedCloud {
  const std::vector<WeightedPoint>* pts;
  size_t kdtree_get_point_count() const { return pts->size(); }
  double kdtree_get_pt(size_t i, size_t dim) const { return (*pts)[i].p[dim]; }
  template <class BBox>
  bool kdtree_get_bbox(BBox&) const {
    return false;
  }
};
/// A nanoflann result set that sums the weighted points of a flat window as the search finds
/// them, instead of listing them for a second pass. The sums are exact integers, so a window's
/// mean depends on which points it holds, not on the order the search finds them in.
struct WindowSum {
  const std::vector<WeightedPoint>* pts;
  double radius2;
  int64_t w = 0;
  int64_t q[3] = {0, 0, 0};
  bool addPoint(double dist2, size_t i) {
    if (dist2 < radius2) {
      const WeightedPoint& pt = (*pts)[i];
      w += pt.w;
      for (int a = 0; a < 3; ++a) q[a] += pt.q[a];
    }
    return true;
  }
  double worstDist() const { return radius2; }
  bool full() const { return true; }
};
using WeightedKdTree =
    nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<double, WeightedCloud>,
                                        WeightedCloud, 3, size_t>;

/// Mean shift with a flat kernel; converged modes closer than `radius` merge (the one with more
/// weight in its window wins). Seeds are the weighted means of the points in each cell of a
/// grid of side radius / 2 ("bin seeding"): points sharing a cell are closer than the radius,
/// so two clusters that mean shift keeps apart never share a seed, and there are tens of seeds
/// instead of one per point (thousands at R = 64). Window queries go through a k-d tree.
std::vector<Vec3> meanShift(const std::vector<WeightedPoint>& pts, double radius, int threads,
                            const Vec3& origin, double half_cell) {
  if (pts.empty()) return {};
  struct Mode {
    Vec3 x;
    double density;
  };
  // Integer sums here too, so that the seeds, like the windows, depend on the set of points and
  // not on their order.
  auto meanOf = [&](int64_t w, const int64_t* q) {
    return Vec3(origin + half_cell *
                             Vec3(static_cast<double>(q[0]), static_cast<double>(q[1]),
                                  static_cast<double>(q[2])) /
                             static_cast<double>(w));
  };
  std::map<std::array<int64_t, 3>, WeightedPoint> cells;
  const double cell = 0.5 * radius;
  for (const WeightedPoint& pt : pts) {
    const std::array<int64_t, 3> key = {static_cast<int64_t>(std::floor(pt.p.x() / cell)),
                                        static_cast<int64_t>(std::floor(pt.p.y() / cell)),
                                        static_cast<int64_t>(std::floor(pt.p.z() / cell))};
    WeightedPoint& c = cells.try_emplace(key).first->second;
    c.w += pt.w;
    for (int a = 0; a < 3; ++a) c.q[a] += pt.q[a];
  }
  std::vector<Vec3> seeds;
  for (const auto& [key, c] : cells) seeds.push_back(meanOf(c.w, c.q));
  const WeightedCloud cloud{&pts};
  WeightedKdTree tree(3, cloud, nanoflann::KDTreeSingleIndexAdaptorParams(32));
  tree.buildIndex();
  const double r2 = radius * radius;
  std::vector<Mode> climbed(seeds.size(), Mode{Vec3::Zero(), 0.0});
#pragma omp parallel for schedule(dynamic, 1) num_threads(threads)
  for (size_t s = 0; s < seeds.size(); ++s) {
    Vec3 x = seeds[s];
    double density = 0;
    for (int it = 0; it < 100; ++it) {
      WindowSum window{&pts, r2};
      tree.findNeighbors(window, x.data(), nanoflann::SearchParams(32, 0.0, false));
      if (window.w <= 0) break;
      const Vec3 next = meanOf(window.w, window.q);
      density = static_cast<double>(window.w);
      const double shift = (next - x).norm();
      x = next;
      if (shift < 1e-3 * radius) break;
    }
    climbed[s] = {x, density};
  }
  std::vector<Mode> modes;
  for (const Mode& m : climbed)
    if (m.density > 0) modes.push_back(m);
  std::sort(modes.begin(), modes.end(),
            [](const Mode& a, const Mode& b) { return a.density > b.density; });
  std::vector<Vec3> centres;
  for (const Mode& m : modes) {
    bool merged = false;
    for (const Vec3& c : centres) merged = merged || (c - m.x).squaredNorm() < r2;
    if (merged) continue;
    centres.push_back(m.x);
    if (centres.size() > kMaxHoughCentres) {
      std::ostringstream text;  // the radius is hough.bandwidth_m, or crowded.bandwidth_m
      text << "Hough voting: more than " << kMaxHoughCentres << " vote centres with a mean-shift "
           << "radius of " << radius << " m (hough.bandwidth_m, or crowded.bandwidth_m in a "
           << "crowded pile's second split): the radius is far below the votes' spread";
      throw TooManyHoughCentres(text.str());
    }
  }
  return centres;
}

using FineCount = uint16_t;

void checkHoughInput(const Grid3<float>& tsdf_m, const Grid3<Vec3f>& votes,
                     const HoughConfig& config) {
  // First: a NaN size or origin would also fail the comparison of the two grids below.
  const GridSpec& g = tsdf_m.spec;
  if (!(std::isfinite(g.voxel_size_m) && g.voxel_size_m > 0.0) || !g.origin_table.allFinite())
    throw std::invalid_argument(
        "houghInstances: the grid needs a finite voxel size > 0 and a finite origin");
  if (!(tsdf_m.spec == votes.spec) || tsdf_m.data.size() != votes.data.size() ||
      static_cast<int>(tsdf_m.data.size()) != tsdf_m.spec.voxelCount())
    throw std::invalid_argument("houghInstances: the TSDF and the vote field must share a grid");
  config.validate();
  if (static_cast<int64_t>(tsdf_m.spec.resolution) * config.refinement > kMaxHoughFineCells)
    throw std::invalid_argument("houghInstances: resolution x refinement too large");
}

/// Occupied voxels (tsdf <= 0) tile by tile (4^3 voxels, tiles and the voxels inside them in
/// raster order; a counting sort of the raster list): neighbouring voxels' fine counts lie
/// close in memory, so a ray's next blocks are more often in cache, and a chunk of consecutive
/// rays starts in one compact part of the pile. `occ` gets 1 per occupied voxel.
std::vector<int> occupiedTileOrder(const Grid3<float>& tsdf_m, std::vector<uint8_t>* occ) {
  const GridSpec& g = tsdf_m.spec;
  occ->assign(g.voxelCount(), 0);
  std::vector<int> occupied;
  for (int i = 0; i < g.voxelCount(); ++i) {
    if (tsdf_m.data[i] <= 0.0f) {
      (*occ)[i] = 1;
      occupied.push_back(i);
    }
  }
  constexpr int kTile = 4;
  const int tiles = (g.resolution + kTile - 1) / kTile;
  auto tileOf = [&](int index) {
    const Vec3i v = g.unravel(index);
    return ((v.z() / kTile) * tiles + v.y() / kTile) * tiles + v.x() / kTile;
  };
  std::vector<int> start(static_cast<size_t>(tiles) * tiles * tiles + 1, 0);
  for (const int i : occupied) ++start[tileOf(i) + 1];
  std::partial_sum(start.begin(), start.end(), start.begin());
  std::vector<int> tiled(occupied.size());
  for (const int i : occupied) tiled[start[tileOf(i)]++] = i;
  return tiled;
}

/// The fine counts of every thread: ref^3 per occupied voxel, in the order of `occupied`.
struct FineCounts {
  std::vector<std::unique_ptr<FineCount[]>> per_thread;
  int team = 1;  ///< threads that ran (the team may be smaller than asked for)
  size_t block = 0;
  size_t traversals = 0;
};

/// Step 1, the rays. A ray is only counted inside occupied voxels (its `outside_tolerance_vox`
/// steps through free space cross gaps, they do not vote), so the fine counts are ref^3 per
/// occupied voxel: sparse, and a ray's cells in one voxel share a few cache lines. The march is
/// bound by the latency of its scattered increments, so counts are 16-bit and saturating, one
/// array per thread, plain increments summed after the march.
FineCounts countRays(const GridSpec& g, const std::vector<int>& occupied,
                     const std::vector<uint8_t>& occ, const std::vector<Vec3>& dirs,
                     const HoughConfig& config, int threads) {
  const int r = g.resolution, ref = config.refinement;
  std::vector<int> block_of(g.voxelCount(), -1);
  for (size_t k = 0; k < occupied.size(); ++k) block_of[occupied[k]] = static_cast<int>(k);
  const std::vector<uint64_t> axis_tables[3] = {fineAxisTable(r, ref, 0), fineAxisTable(r, ref, 1),
                                                fineAxisTable(r, ref, 2)};
  FineCounts out;
  out.block = static_cast<size_t>(ref) * ref * ref;
  const size_t block = out.block;
  // The counts take `block` cells per occupied voxel and thread: within a budget, by fewer
  // threads, or refused (new[] touches no page; an out-of-memory kill would come later).
  constexpr size_t kBudgetBytes = size_t{2} << 30;
  const size_t per_thread = occupied.size() * block * sizeof(FineCount);
  if (per_thread > kBudgetBytes) {
    std::ostringstream text;
    text << "Hough voting: hough.refinement " << ref << " needs " << per_thread / (1 << 20)
         << " MB of ray counts for " << occupied.size()
         << " occupied voxels, over the 2048 MB budget: lower the refinement";
    throw std::invalid_argument(text.str());
  }
  threads = std::max<int>(1, std::min<size_t>(threads, kBudgetBytes / per_thread));
  // Allocated here (a bad_alloc inside a parallel region would terminate), zeroed by the thread
  // that uses it (first touch); only the arrays of the threads that ran are summed.
  out.per_thread.resize(threads);
  for (auto& counts : out.per_thread) counts.reset(new FineCount[occupied.size() * block]);
  std::vector<size_t> visits(threads, 0);
  int team = 1;
#pragma omp parallel num_threads(threads)
  {
    const int t = omp_get_thread_num();
#pragma omp single
    team = omp_get_num_threads();
    FineCount* const counts = out.per_thread[t].get();
    std::fill(counts, counts + occupied.size() * block, FineCount{0});
#pragma omp for schedule(dynamic, 512)  // rays differ in length; counts add up the same
    for (size_t k = 0; k < occupied.size(); ++k) {
      if (dirs[k].squaredNorm() == 0) continue;
      const Vec3 p = (g.unravel(occupied[k]).cast<double>() + Vec3::Constant(0.5)) * ref;
      const Vec3& d = dirs[k];
      visits[t] += marchRay<FineCount>(p, d, ref, occ, r, config.outside_tolerance_vox, axis_tables,
                                       [&](int voxel) {
                                         const int b = block_of[voxel];
                                         return b >= 0 ? counts + b * block : nullptr;
                                       });
    }
  }
  out.team = team;
  out.traversals = std::accumulate(visits.begin(), visits.end(), size_t{0});
  return out;
}

/// Step 2: cells above mu (the threads' counts summed), gathered per scene voxel into their
/// count-weighted mean position and total count: the points of mean shift. `candidates` gets
/// the number of such cells.
std::vector<WeightedPoint> centreVotes(const GridSpec& g, const std::vector<int>& occupied,
                                       const FineCounts& fc, const HoughConfig& config, int threads,
                                       int* candidates_out) {
  const int ref = config.refinement;
  const double h = g.voxel_size_m / ref;
  const size_t block = fc.block;
  std::vector<WeightedPoint> per_voxel(occupied.size());
  int candidates = 0;
  std::vector<std::vector<uint32_t>> sums(threads, std::vector<uint32_t>(block));
#pragma omp parallel num_threads(threads) reduction(+ : candidates)
  {
    std::vector<uint32_t>& sum = sums[omp_get_thread_num()];
#pragma omp for schedule(static)
    for (size_t b = 0; b < occupied.size(); ++b) {
      const FineCount* first = fc.per_thread[0].get() + b * block;
      for (size_t i = 0; i < block; ++i) sum[i] = first[i];
      for (int t = 1; t < fc.team; ++t) {
        const FineCount* counts = fc.per_thread[t].get() + b * block;
        for (size_t i = 0; i < block; ++i) sum[i] += counts[i];
      }
      uint32_t most = 0;
      for (size_t i = 0; i < block; ++i) most = std::max(most, sum[i]);
      if (static_cast<int64_t>(most) <= config.min_traversals) continue;  // most voxels
      // Counts times in-voxel cell indices, summed exactly in integers; the voxel's weighted
      // mean position follows from them once.
      uint64_t weight = 0, lsum[3] = {0, 0, 0};
      for (int lz = 0, i = 0; lz < ref; ++lz) {
        for (int ly = 0; ly < ref; ++ly) {
          for (int lx = 0; lx < ref; ++lx, ++i) {
            const uint32_t c = sum[i];
            if (static_cast<int64_t>(c) <= config.min_traversals) continue;
            ++candidates;
            weight += c;
            lsum[0] += uint64_t{c} * lx;
            lsum[1] += uint64_t{c} * ly;
            lsum[2] += uint64_t{c} * lz;
          }
        }
      }
      if (weight == 0) continue;
      const Vec3i v = g.unravel(occupied[b]);
      const double w = static_cast<double>(weight);
      WeightedPoint& bin = per_voxel[b];
      bin.w = static_cast<int64_t>(weight);
      for (int a = 0; a < 3; ++a)
        bin.q[a] = 2 * (static_cast<int64_t>(weight) * ref * v[a] + static_cast<int64_t>(lsum[a])) +
                   static_cast<int64_t>(weight);
      bin.p = g.origin_table + h * (ref * v.cast<double>() + Vec3::Constant(0.5) +
                                    Vec3(static_cast<double>(lsum[0]), static_cast<double>(lsum[1]),
                                         static_cast<double>(lsum[2])) /
                                        w);
    }
  }
  *candidates_out = candidates;
  std::vector<WeightedPoint> bins;
  for (const WeightedPoint& bin : per_voxel)
    if (bin.w > 0) bins.push_back(bin);
  return bins;
}

/// Step 3: each occupied voxel joins the centre minimising |angle to its vote| + gamma *
/// distance / voxel; centres with fewer than `min_instance_voxels` voxels are dropped and the
/// assignment repeated. Instances are numbered largest first into `out`.
void assignToCentres(const GridSpec& g, const std::vector<int>& occupied,
                     const std::vector<Vec3>& dirs, std::vector<Vec3> centres,
                     const HoughConfig& config, int threads, InstanceSegmentation* out) {
  std::vector<Vec3> positions(occupied.size());
  for (size_t k = 0; k < occupied.size(); ++k) {
    const Vec3i idx = g.unravel(occupied[k]);
    positions[k] = g.voxelCentre(idx.x(), idx.y(), idx.z());
  }
  std::vector<int> assignment(occupied.size(), -1);
  while (!centres.empty()) {
#pragma omp parallel for schedule(static) num_threads(threads)
    for (size_t k = 0; k < occupied.size(); ++k) {
      double best = std::numeric_limits<double>::infinity();
      int best_n = -1;
      for (size_t n = 0; n < centres.size(); ++n) {
        const Vec3 u = centres[n] - positions[k];
        const double dist = u.norm();
        double cost = config.gamma * dist / g.voxel_size_m;
        if (!(cost < best)) continue;  // the angle only adds: no need to compute it
        if (dirs[k].squaredNorm() > 0 && dist > 1e-9)
          cost += std::abs(std::acos(std::clamp(dirs[k].dot(u) / dist, -1.0, 1.0)));
        if (cost < best) {
          best = cost;
          best_n = static_cast<int>(n);
        }
      }
      assignment[k] = best_n;
    }
    std::vector<int> counts(centres.size(), 0);
    for (const int n : assignment) {
      SIMSTACK_ASSERT(n >= 0, "houghInstances: a voxel was assigned to no centre");
      ++counts[n];
    }
    std::vector<Vec3> kept;
    for (size_t n = 0; n < centres.size(); ++n)
      if (counts[n] >= config.min_instance_voxels) kept.push_back(centres[n]);
    if (kept.size() == centres.size()) {
      std::vector<int> order(centres.size());
      std::iota(order.begin(), order.end(), 0);
      std::stable_sort(order.begin(), order.end(),
                       [&](int a, int b) { return counts[a] > counts[b]; });
      std::vector<int> rank(centres.size());
      for (size_t i = 0; i < order.size(); ++i) {
        rank[order[i]] = static_cast<int>(i);
        out->centres_table.push_back(centres[order[i]]);
        out->voxel_counts.push_back(counts[order[i]]);
      }
      for (size_t k = 0; k < occupied.size(); ++k)
        out->labels.data[occupied[k]] = rank[assignment[k]];
      return;
    }
    centres = std::move(kept);
  }
}

}  // namespace

void HoughConfig::validate() const {
  const auto require = [](bool ok, const std::string& field, double value, const char* range) {
    if (ok) return;
    std::ostringstream text;  // -1, 0.05, nan, 1e+300: as a person writes them
    text << "hough." << field << " must be " << range << ", not " << value;
    throw std::invalid_argument(text.str());
  };
  // 16^3 fine cells per voxel already take 8 kB per occupied voxel and thread in the ray counts.
  require(refinement >= 1 && refinement <= 16, "refinement", refinement, "in [1, 16]");
  require(min_traversals >= 0, "min_traversals", min_traversals, ">= 0");
  // A non-finite weight would leave voxels with no centre at all.
  require(std::isfinite(gamma) && gamma >= 0 && gamma <= 1e6, "gamma", gamma, "in [0, 1e6]");
  // A millimetre is far below a voxel; the live setting (LiveSettings.cfg) has the same range.
  require(std::isfinite(bandwidth_m) && bandwidth_m >= 0.001 && bandwidth_m <= 10, "bandwidth_m",
          bandwidth_m, "in [0.001, 10] m");
  require(min_instance_voxels >= 1, "min_instance_voxels", min_instance_voxels, ">= 1");
  // The votes' targets are unit directions, and the network shortens the votes it is unsure
  // of: from 1 on, next to none would cast a ray and every scene would be empty.
  require(min_vote_norm >= 0 && min_vote_norm < 1, "min_vote_norm", min_vote_norm, "in [0, 1)");
  require(outside_tolerance_vox >= 0, "outside_tolerance_vox", outside_tolerance_vox, ">= 0");
  require(threads >= 1, "threads", threads, ">= 1");
}

InstanceSegmentation houghInstances(const Grid3<float>& tsdf_m, const Grid3<Vec3f>& votes,
                                    const HoughConfig& config) {
  checkHoughInput(tsdf_m, votes, config);
  const GridSpec& g = tsdf_m.spec;
  const double h = g.voxel_size_m / config.refinement;
  InstanceSegmentation out;
  out.labels = Grid3<int>(g, -1);
  std::vector<uint8_t> occ;
  const std::vector<int> occupied = occupiedTileOrder(tsdf_m, &occ);
  if (occupied.empty()) return out;
  const int threads = std::max(1, std::min(config.threads, static_cast<int>(occupied.size())));
  std::vector<Vec3> dirs(occupied.size(), Vec3::Zero());
  for (size_t k = 0; k < occupied.size(); ++k) {
    const Vec3f v = votes.data[occupied[k]];
    if (v.norm() > std::max(1e-3, config.min_vote_norm)) dirs[k] = (v / v.norm()).cast<double>();
  }
  using Clock = std::chrono::steady_clock;
  auto ms = [](Clock::time_point a) {
    return std::chrono::duration<double, std::milli>(Clock::now() - a).count();
  };
  const auto t0 = Clock::now();
  const FineCounts counts = countRays(g, occupied, occ, dirs, config, threads);
  out.traversals = counts.traversals;
  out.count_bytes = counts.team * occupied.size() * counts.block * sizeof(FineCount);
  out.timings.rays_ms = ms(t0);

  const auto t1 = Clock::now();
  const std::vector<WeightedPoint> bins =
      centreVotes(g, occupied, counts, config, threads, &out.candidate_cells);
  std::vector<Vec3> centres = meanShift(bins, config.bandwidth_m, threads, g.origin_table, 0.5 * h);
  out.timings.mean_shift_ms = ms(t1);

  const auto t2 = Clock::now();
  assignToCentres(g, occupied, dirs, std::move(centres), config, threads, &out);
  out.timings.assign_ms = ms(t2);
  return out;
}

}  // namespace simstack
