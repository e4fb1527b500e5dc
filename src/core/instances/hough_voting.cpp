#include "simstack/instances/hough_voting.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <numeric>
#include <stdexcept>

namespace simstack {
namespace {

/// Open-addressing counter keyed by a fine-cell index (linear probing, power-of-two size).
class CellCounter {
 public:
  CellCounter() { resize(1 << 14); }
  void add(uint32_t key, uint32_t amount = 1) {
    if (2 * (used_ + 1) > keys_.size()) resize(keys_.size() * 2);
    size_t i = hash(key) & mask_;
    while (true) {
      if (keys_[i] == kEmpty) {
        keys_[i] = key;
        counts_[i] = amount;
        ++used_;
        return;
      }
      if (keys_[i] == key) {
        counts_[i] += amount;
        return;
      }
      i = (i + 1) & mask_;
    }
  }
  template <class F>
  void forEach(F&& f) const {
    for (size_t i = 0; i < keys_.size(); ++i)
      if (keys_[i] != kEmpty) f(keys_[i], counts_[i]);
  }

 private:
  static constexpr uint32_t kEmpty = 0xFFFFFFFFu;
  static size_t hash(uint32_t k) { return (static_cast<uint64_t>(k) * 0x9E3779B97F4A7C15ull) >> 20; }
  void resize(size_t capacity) {
    std::vector<uint32_t> old_keys = std::move(keys_), old_counts = std::move(counts_);
    keys_.assign(capacity, kEmpty);
    counts_.assign(capacity, 0);
    mask_ = capacity - 1;
    used_ = 0;
    for (size_t i = 0; i < old_keys.size(); ++i)
      if (old_keys[i] != kEmpty) add(old_keys[i], old_counts[i]);
  }
  std::vector<uint32_t> keys_, counts_;
  size_t mask_ = 0, used_ = 0;
};

/// Marches the ray from fine-grid point `p` along unit `d` (Amanatides & Woo), counting every
/// fine cell once while the ray stays in (or within `tolerance` voxels of) occupied space.
size_t marchRay(const Vec3& p, const Vec3& d, int ref, int fine, const std::vector<uint8_t>& occ,
                int r, int tolerance, CellCounter* counter) {
  int cell[3], step[3];
  double t_max[3], t_delta[3];
  for (int a = 0; a < 3; ++a) {
    cell[a] = static_cast<int>(std::floor(p[a]));
    if (d[a] > 1e-12) {
      step[a] = 1;
      t_max[a] = (cell[a] + 1 - p[a]) / d[a];
      t_delta[a] = 1.0 / d[a];
    } else if (d[a] < -1e-12) {
      step[a] = -1;
      t_max[a] = (p[a] - cell[a]) / -d[a];
      t_delta[a] = -1.0 / d[a];
    } else {
      step[a] = 0;
      t_max[a] = t_delta[a] = std::numeric_limits<double>::infinity();
    }
  }
  size_t visits = 0;
  int outside = 0, last_voxel = -1;
  while (cell[0] >= 0 && cell[1] >= 0 && cell[2] >= 0 && cell[0] < fine && cell[1] < fine &&
         cell[2] < fine) {
    const int voxel = ((cell[2] / ref) * r + cell[1] / ref) * r + cell[0] / ref;
    if (voxel != last_voxel) {
      last_voxel = voxel;
      outside = occ[voxel] ? 0 : outside + 1;
      if (outside > tolerance) break;
    }
    counter->add((static_cast<uint32_t>(cell[2]) * fine + cell[1]) * fine + cell[0]);
    ++visits;
    const int a = t_max[0] < t_max[1] ? (t_max[0] < t_max[2] ? 0 : 2) : (t_max[1] < t_max[2] ? 1 : 2);
    cell[a] += step[a];
    t_max[a] += t_delta[a];
  }
  return visits;
}

struct WeightedPoint {
  Vec3 p;
  double w;
};

/// Mean shift with a flat kernel from every point; converged modes closer than `radius` merge
/// (the one with more weight in its window wins).
std::vector<Vec3> meanShift(const std::vector<WeightedPoint>& pts, double radius) {
  struct Mode {
    Vec3 x;
    double density;
  };
  std::vector<Mode> modes;
  const double r2 = radius * radius;
  for (const WeightedPoint& seed : pts) {
    Vec3 x = seed.p;
    double density = 0;
    for (int it = 0; it < 100; ++it) {
      Vec3 sum = Vec3::Zero();
      double w = 0;
      for (const WeightedPoint& q : pts) {
        if ((q.p - x).squaredNorm() <= r2) {
          sum += q.w * q.p;
          w += q.w;
        }
      }
      if (w <= 0) break;
      const Vec3 next = sum / w;
      density = w;
      const double shift = (next - x).norm();
      x = next;
      if (shift < 1e-3 * radius) break;
    }
    modes.push_back({x, density});
  }
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
  if (config.refinement < 1 || config.min_traversals < 0 || config.bandwidth_vox <= 0)
    throw std::invalid_argument("houghInstances: refinement >= 1, min_traversals >= 0 and "
                                "bandwidth_vox > 0 are required");
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

  // 1. Rays, counted per thread, then merged.
  const int threads = std::max(1, std::min(config.threads, static_cast<int>(occupied.size())));
  std::vector<CellCounter> counters(threads);
  std::vector<size_t> visits(threads, 0);
#pragma omp parallel num_threads(threads)
  {
    const int t = omp_get_thread_num();
#pragma omp for schedule(static)
    for (size_t k = 0; k < occupied.size(); ++k) {
      const Vec3f v = votes.data[occupied[k]];
      const float n = v.norm();
      if (!(n > 1e-3f)) continue;
      const Vec3i idx = g.unravel(occupied[k]);
      const Vec3 p = (idx.cast<double>() + Vec3::Constant(0.5)) * ref;
      visits[t] += marchRay(p, (v / n).cast<double>(), ref, fine, occ, r,
                            config.outside_tolerance_vox, &counters[t]);
    }
  }
  for (int t = 1; t < threads; ++t)
    counters[t].forEach([&](uint32_t key, uint32_t c) { counters[0].add(key, c); });
  out.traversals = std::accumulate(visits.begin(), visits.end(), size_t{0});

  // 2. Cells above mu, gathered per scene voxel (weighted by count) to seed mean shift.
  std::vector<WeightedPoint> bins(g.voxelCount(), WeightedPoint{Vec3::Zero(), 0.0});
  counters[0].forEach([&](uint32_t key, uint32_t c) {
    if (static_cast<int>(c) <= config.min_traversals) return;
    ++out.candidate_cells;
    const int fx = key % fine, fy = (key / fine) % fine, fz = key / (fine * fine);
    const Vec3 p = g.origin_table + h * Vec3(fx + 0.5, fy + 0.5, fz + 0.5);
    WeightedPoint& b = bins[g.linear(fx / ref, fy / ref, fz / ref)];
    b.p += c * p;
    b.w += c;
  });
  std::vector<WeightedPoint> seeds;
  for (const WeightedPoint& b : bins)
    if (b.w > 0) seeds.push_back({b.p / b.w, b.w});
  std::vector<Vec3> centres = meanShift(seeds, config.bandwidth_vox * g.voxel_size_m);

  // 3. Assignment; instances below the size limit are dropped and their voxels re-assigned.
  std::vector<Vec3> positions(occupied.size()), dirs(occupied.size());
  for (size_t k = 0; k < occupied.size(); ++k) {
    const Vec3i idx = g.unravel(occupied[k]);
    positions[k] = g.voxelCentre(idx.x(), idx.y(), idx.z());
    const Vec3f v = votes.data[occupied[k]];
    dirs[k] = v.norm() > 1e-3f ? Vec3((v / v.norm()).cast<double>()) : Vec3::Zero();
  }
  std::vector<int> assignment(occupied.size(), -1);
  while (!centres.empty()) {
    std::vector<int> counts(centres.size(), 0);
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
      ++counts[best_n];
    }
    std::vector<Vec3> kept;
    for (size_t n = 0; n < centres.size(); ++n)
      if (counts[n] >= config.min_instance_voxels) kept.push_back(centres[n]);
    if (kept.size() == centres.size()) {
      // Largest instance first.
      std::vector<int> order(centres.size());
      std::iota(order.begin(), order.end(), 0);
      std::stable_sort(order.begin(), order.end(), [&](int a, int b) { return counts[a] > counts[b]; });
      std::vector<int> rank(centres.size());
      for (size_t i = 0; i < order.size(); ++i) {
        rank[order[i]] = static_cast<int>(i);
        out.centres_table.push_back(centres[order[i]]);
        out.voxel_counts.push_back(counts[order[i]]);
      }
      for (size_t k = 0; k < occupied.size(); ++k) out.labels.data[occupied[k]] = rank[assignment[k]];
      break;
    }
    centres = std::move(kept);
  }
  return out;
}

}  // namespace simstack
