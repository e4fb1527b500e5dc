#include "simstack/instances/hough_voting.h"

#include "simstack/instances/convex_split.h"

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
#include <stdexcept>

namespace simstack {
namespace {

/// Marches the ray from fine-grid point `p` along unit `d` (Amanatides & Woo), visiting every
/// fine cell once while the ray stays in (or within `tolerance` voxels of) occupied space.
/// `block(scene voxel)` gives that voxel's ref^3 fine counts (nullptr: not counted); each fine
/// cell crossed bumps its count, saturating. Voxel and in-voxel coordinates are stepped along
/// with the cell, so the loop has no division, and the block is looked up once per voxel, not
/// once per cell. On entering a voxel the ray already knows the voxel it will enter next, whose
/// block is prefetched while this voxel's cells are counted.
template <class Count, class Block, class Reversed>
size_t marchRay(const Vec3& p, const Vec3& d, int ref, const std::vector<uint8_t>& occ, int r,
                int tolerance, int reversed_stop, Block&& block_of, Reversed&& reversed) {
  int voxel[3], local[3], step[3];
  double t_max[3], t_delta[3];
  for (int a = 0; a < 3; ++a) {
    const int cell = static_cast<int>(std::floor(p[a]));
    voxel[a] = cell / ref;  // p is inside the grid: cell >= 0
    local[a] = cell - voxel[a] * ref;
    if (d[a] > 1e-12) {
      step[a] = 1;
      t_max[a] = (cell + 1 - p[a]) / d[a];
      t_delta[a] = 1.0 / d[a];
    } else if (d[a] < -1e-12) {
      step[a] = -1;
      t_max[a] = (p[a] - cell) / -d[a];
      t_delta[a] = -1.0 / d[a];
    } else {
      step[a] = 0;
      t_max[a] = t_delta[a] = std::numeric_limits<double>::infinity();
    }
  }
  // The axis to step is picked without branches (which axis comes next is close to random, and
  // mispredicting it cost more than the step); the loop only branches when the ray leaves a
  // scene voxel, once per `ref` steps or so. Ties go to the later axis.
  double tx = t_max[0], ty = t_max[1], tz = t_max[2];
  int lx = local[0], ly = local[1], lz = local[2];
  int vx = voxel[0], vy = voxel[1], vz = voxel[2];
  const unsigned n = static_cast<unsigned>(ref);  // as unsigned, a negative index is >= n
  const int stride[3] = {step[0], step[1] * ref, step[2] * ref * ref};
  size_t visits = 0;
  int outside = 0, reversed_run = 0;
  while (true) {
    if (vx < 0 || vy < 0 || vz < 0 || vx >= r || vy >= r || vz >= r) break;
    const int index = (vz * r + vy) * r + vx;
    outside = occ[index] ? 0 : outside + 1;
    if (outside > tolerance) break;
    if (reversed_stop > 0) {
      reversed_run = occ[index] && reversed(index) ? reversed_run + 1 : 0;
      if (reversed_run >= reversed_stop) break;
    }
    Count* const block = block_of(index);
    {
      // Parameter at which each in-voxel index leaves [0, ref); the smallest one is the exit.
      const double ex = step[0] ? tx + (step[0] > 0 ? ref - 1 - lx : lx) * t_delta[0] : tx;
      const double ey = step[1] ? ty + (step[1] > 0 ? ref - 1 - ly : ly) * t_delta[1] : ty;
      const double ez = step[2] ? tz + (step[2] > 0 ? ref - 1 - lz : lz) * t_delta[2] : tz;
      const int a = ex < ey ? (ex < ez ? 0 : 2) : (ey < ez ? 1 : 2);
      const int next[3] = {vx + (a == 0) * step[0], vy + (a == 1) * step[1],
                           vz + (a == 2) * step[2]};
      if (static_cast<unsigned>(next[0]) < static_cast<unsigned>(r) &&
          static_cast<unsigned>(next[1]) < static_cast<unsigned>(r) &&
          static_cast<unsigned>(next[2]) < static_cast<unsigned>(r))
        if (const Count* upcoming = block_of((next[2] * r + next[1]) * r + next[0]))
          for (size_t byte = 0; byte < sizeof(Count) * ref * ref * ref; byte += 64)
            __builtin_prefetch(reinterpret_cast<const char*>(upcoming) + byte, 1);
    }
    int li = (lz * ref + ly) * ref + lx;
    while (true) {  // the fine cells of this voxel
      if (block) {
        Count& c = block[li];
        c += c != std::numeric_limits<Count>::max();
      }
      ++visits;
      const bool x_before_y = tx < ty;
      const bool bx = x_before_y & (tx < tz);
      const bool by = !x_before_y & (ty < tz);
      const bool bz = !(bx | by);
      tx += bx ? t_delta[0] : 0.0;
      ty += by ? t_delta[1] : 0.0;
      tz += bz ? t_delta[2] : 0.0;
      lx += bx * step[0];
      ly += by * step[1];
      lz += bz * step[2];
      li += bx ? stride[0] : by ? stride[1] : stride[2];
      if ((static_cast<unsigned>(lx) >= n) | (static_cast<unsigned>(ly) >= n) |
          (static_cast<unsigned>(lz) >= n))
        break;
    }
    // Exactly one in-voxel index has left [0, ref) by one cell: wrap it, step that voxel index.
    int& l = static_cast<unsigned>(lx) >= n ? lx : static_cast<unsigned>(ly) >= n ? ly : lz;
    int& v = &l == &lx ? vx : &l == &ly ? vy : vz;
    const int dir = l < 0 ? -1 : 1;
    l -= dir * ref;
    v += dir;
  }
  return visits;
}

struct WeightedPoint {
  Vec3 p;
  double w;
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
/// them, instead of listing them for a second pass.
struct WindowSum {
  const std::vector<WeightedPoint>* pts;
  double radius2;
  Vec3 sum = Vec3::Zero();
  double w = 0;
  bool addPoint(double dist2, size_t i) {
    if (dist2 < radius2) {
      sum += (*pts)[i].w * (*pts)[i].p;
      w += (*pts)[i].w;
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
/// so two clusters that mean shift keeps apart never share a seed (cells of side `radius`
/// merged centres 7-12 cm apart), and there are tens of seeds instead of one per point
/// (thousands at R = 64). Window queries go through a k-d tree.
std::vector<Vec3> meanShift(const std::vector<WeightedPoint>& pts, double radius, int threads) {
  if (pts.empty()) return {};
  struct Mode {
    Vec3 x;
    double density;
  };
  std::map<std::array<int64_t, 3>, WeightedPoint> cells;
  const double cell = 0.5 * radius;
  for (const WeightedPoint& q : pts) {
    const std::array<int64_t, 3> key = {static_cast<int64_t>(std::floor(q.p.x() / cell)),
                                        static_cast<int64_t>(std::floor(q.p.y() / cell)),
                                        static_cast<int64_t>(std::floor(q.p.z() / cell))};
    WeightedPoint& c = cells.try_emplace(key, WeightedPoint{Vec3::Zero(), 0.0}).first->second;
    c.p += q.w * q.p;
    c.w += q.w;
  }
  std::vector<Vec3> seeds;
  for (const auto& [key, c] : cells) seeds.push_back(c.p / c.w);
  const WeightedCloud cloud{&pts};
  WeightedKdTree tree(3, cloud, nanoflann::KDTreeSingleIndexAdaptorParams(16));
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
      const Vec3 next = window.sum / window.w;
      density = window.w;
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
    if (!merged) centres.push_back(m.x);
  }
  return centres;
}

}  // namespace

InstanceSegmentation houghInstances(const Grid3<float>& tsdf_m, const Grid3<Vec3f>& votes,
                                    const HoughConfig& config) {
  if (!(tsdf_m.spec == votes.spec) || tsdf_m.data.size() != votes.data.size() ||
      static_cast<int>(tsdf_m.data.size()) != tsdf_m.spec.voxelCount())
    throw std::invalid_argument("houghInstances: the TSDF and the vote field must share a grid");
  if (config.refinement < 1 || config.min_traversals < 0 || config.bandwidth_m <= 0)
    throw std::invalid_argument(
        "houghInstances: refinement >= 1, min_traversals >= 0 and "
        "bandwidth_m > 0 are required");
  if (config.split_below_solidity < 0 || config.split_below_solidity > 1 ||
      config.split_accept_solidity <= 0 || config.split_accept_solidity > 1 ||
      config.split_max_rounds < 0)
    throw std::invalid_argument(
        "houghInstances: split solidities in [0, 1] (accept > 0) and "
        "split_max_rounds >= 0 are required");
  const GridSpec& g = tsdf_m.spec;
  const int r = g.resolution, ref = config.refinement, fine = r * ref;
  if (static_cast<double>(fine) * fine * fine >= 4294967295.0)
    throw std::invalid_argument("houghInstances: resolution x refinement too large");
  const double h = g.voxel_size_m / ref;

  InstanceSegmentation out;
  out.labels = Grid3<int>(g, -1);
  std::vector<uint8_t> occ(g.voxelCount(), 0);
  std::vector<int> occupied;
  for (int i = 0; i < g.voxelCount(); ++i) {
    if (tsdf_m.data[i] <= 0.0f) {
      occ[i] = 1;
      occupied.push_back(i);
    }
  }
  if (occupied.empty()) return out;
  // Occupied voxels in Morton (z-order) order: neighbouring voxels' fine counts lie close in
  // memory, so a ray's next blocks are more often in cache (rays 0.91-0.94x at R = 64), and a
  // chunk of consecutive rays starts in one compact part of the pile.
  {
    auto spread = [](uint64_t v) {
      uint64_t x = v & 0x1fffff;
      x = (x | x << 32) & 0x1f00000000ffffULL;
      x = (x | x << 16) & 0x1f0000ff0000ffULL;
      x = (x | x << 8) & 0x100f00f00f00f00fULL;
      x = (x | x << 4) & 0x10c30c30c30c30c3ULL;
      x = (x | x << 2) & 0x1249249249249249ULL;
      return x;
    };
    std::vector<std::pair<uint64_t, int>> keyed(occupied.size());
    for (size_t k = 0; k < occupied.size(); ++k) {
      const Vec3i v = g.unravel(occupied[k]);
      keyed[k] = {spread(v.x()) | spread(v.y()) << 1 | spread(v.z()) << 2, occupied[k]};
    }
    std::sort(keyed.begin(), keyed.end());
    for (size_t k = 0; k < occupied.size(); ++k) occupied[k] = keyed[k].second;
  }

  // 1. Rays. A ray is only counted inside occupied voxels (its `outside_tolerance_vox` steps
  //    through free space cross gaps, they do not vote), so the fine counts are ref^3 per
  //    occupied voxel, in the order of `occupied`: sparse, and a ray's cells in one voxel share
  //    a few cache lines. The march is bound by the latency of its scattered increments, so
  //    counts are 16-bit and saturating, one array per thread, plain increments summed after
  //    the march (shared atomic 32-bit counts: 1.25x slower at R = 64), and the next voxel's
  //    block is prefetched (1.13x). A first pass that counted rays per voxel, to give fine
  //    counts only to voxels crossed by more than mu rays, found nearly every occupied voxel
  //    above mu and cost 1.3x more than it saved. Not counting the tolerance steps through free
  //    voxels left the network's object counts unchanged (synthetic test views: 30 % exact
  //    before and after; the same counts on the four real scenes).
  const int threads = std::max(1, std::min(config.threads, static_cast<int>(occupied.size())));
  std::vector<Vec3> dirs(occupied.size(), Vec3::Zero());
  for (size_t k = 0; k < occupied.size(); ++k) {
    const Vec3f v = votes.data[occupied[k]];
    if (v.norm() > std::max(1e-3, config.min_vote_norm)) dirs[k] = (v / v.norm()).cast<double>();
  }
  const auto t0 = std::chrono::steady_clock::now();
  auto ms = [](std::chrono::steady_clock::time_point a) {
    return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - a).count();
  };
  std::vector<int> block_of(g.voxelCount(), -1);
  for (size_t k = 0; k < occupied.size(); ++k) block_of[occupied[k]] = static_cast<int>(k);
  using FineCount = uint16_t;
  const size_t block = static_cast<size_t>(ref) * ref * ref;
  // Allocated here (a bad_alloc inside a parallel region would terminate), zeroed by the thread
  // that uses it (first touch); the team may be smaller than asked for, so only the arrays of
  // the threads that ran are summed.
  std::vector<std::unique_ptr<FineCount[]>> per_thread(threads);
  for (auto& counts : per_thread) counts.reset(new FineCount[occupied.size() * block]);
  std::vector<size_t> visits(threads, 0);
  int team = 1;
#pragma omp parallel num_threads(threads)
  {
    const int t = omp_get_thread_num();
#pragma omp single
    team = omp_get_num_threads();
    FineCount* const counts = per_thread[t].get();
    std::fill(counts, counts + occupied.size() * block, FineCount{0});
#pragma omp for schedule(dynamic, 512)  // rays differ in length; counts add up the same
    for (size_t k = 0; k < occupied.size(); ++k) {
      if (dirs[k].squaredNorm() == 0) continue;
      const Vec3 p = (g.unravel(occupied[k]).cast<double>() + Vec3::Constant(0.5)) * ref;
      const Vec3& d = dirs[k];
      visits[t] += marchRay<FineCount>(
          p, d, ref, occ, r, config.outside_tolerance_vox, config.reversed_vote_stop_vox,
          [&](int voxel) {
            const int b = block_of[voxel];
            return b >= 0 ? counts + b * block : nullptr;
          },
          [&](int voxel) { return dirs[block_of[voxel]].dot(d) < 0.0; });
    }
  }
  out.traversals = std::accumulate(visits.begin(), visits.end(), size_t{0});
  out.count_bytes = team * occupied.size() * block * sizeof(FineCount);

  out.timings.rays_ms = ms(t0);
  const auto t1 = std::chrono::steady_clock::now();

  // 2. Cells above mu (the threads' counts summed), gathered per scene voxel into their
  //    count-weighted mean position and total count: the points of mean shift.
  std::vector<WeightedPoint> per_voxel(occupied.size(), WeightedPoint{Vec3::Zero(), 0.0});
  int candidates = 0;
  std::vector<std::vector<uint32_t>> sums(threads, std::vector<uint32_t>(block));
#pragma omp parallel num_threads(threads) reduction(+ : candidates)
  {
    std::vector<uint32_t>& sum = sums[omp_get_thread_num()];
#pragma omp for schedule(static)
    for (size_t b = 0; b < occupied.size(); ++b) {
      const FineCount* first = per_thread[0].get() + b * block;
      for (size_t i = 0; i < block; ++i) sum[i] = first[i];
      for (int t = 1; t < team; ++t) {
        const FineCount* counts = per_thread[t].get() + b * block;
        for (size_t i = 0; i < block; ++i) sum[i] += counts[i];
      }
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
      bin.w = w;
      bin.p = g.origin_table + h * (ref * v.cast<double>() + Vec3::Constant(0.5) +
                                    Vec3(static_cast<double>(lsum[0]), static_cast<double>(lsum[1]),
                                         static_cast<double>(lsum[2])) /
                                        w);
    }
  }
  out.candidate_cells = candidates;
  std::vector<WeightedPoint> bins;
  for (const WeightedPoint& bin : per_voxel)
    if (bin.w > 0) bins.push_back(bin);
  std::vector<Vec3> centres = meanShift(bins, config.bandwidth_m, threads);
  out.timings.mean_shift_ms = ms(t1);
  const auto t2 = std::chrono::steady_clock::now();

  // 3. Assignment; instances below the size limit are dropped and their voxels re-assigned.
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
    for (const int n : assignment) ++counts[n];
    std::vector<Vec3> kept;
    for (size_t n = 0; n < centres.size(); ++n)
      if (counts[n] >= config.min_instance_voxels) kept.push_back(centres[n]);
    if (kept.size() == centres.size()) {
      // Largest instance first.
      std::vector<int> order(centres.size());
      std::iota(order.begin(), order.end(), 0);
      std::stable_sort(order.begin(), order.end(),
                       [&](int a, int b) { return counts[a] > counts[b]; });
      std::vector<int> rank(centres.size());
      for (size_t i = 0; i < order.size(); ++i) {
        rank[order[i]] = static_cast<int>(i);
        out.centres_table.push_back(centres[order[i]]);
        out.voxel_counts.push_back(counts[order[i]]);
      }
      for (size_t k = 0; k < occupied.size(); ++k)
        out.labels.data[occupied[k]] = rank[assignment[k]];
      break;
    }
    centres = std::move(kept);
  }
  out.splits = splitNonConvexInstances(&out, config);
  out.timings.assign_ms = ms(t2);
  return out;
}

}  // namespace simstack
