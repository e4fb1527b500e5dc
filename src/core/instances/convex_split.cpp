#include "simstack/instances/convex_split.h"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <memory>
#include <numeric>
#include <stdexcept>

#include "simstack/geometry/convex_hull.h"

namespace simstack {

double voxelSolidity(const std::vector<Vec3i>& voxels, const GridSpec& grid) {
  if (voxels.size() < 4) return 1.0;
  std::vector<Vec3> centres;
  centres.reserve(voxels.size());
  Vec3i lo = voxels.front(), hi = voxels.front();
  for (const Vec3i& v : voxels) {
    centres.push_back(grid.voxelCentre(v.x(), v.y(), v.z()));
    lo = lo.cwiseMin(v);
    hi = hi.cwiseMax(v);
  }
  std::unique_ptr<ConvexHull> hull;
  try {
    hull = std::make_unique<ConvexHull>(centres);
  } catch (const std::invalid_argument&) {
    return 1.0;  // flat: nothing to judge
  }
  // Lattice points on the hull's faces count as inside (the set's own centres lie there).
  const double tolerance = 1e-3 * grid.voxel_size_m;
  long inside = 0;
  for (int z = lo.z(); z <= hi.z(); ++z)
    for (int y = lo.y(); y <= hi.y(); ++y)
      for (int x = lo.x(); x <= hi.x(); ++x)
        inside += hull->contains(grid.voxelCentre(x, y, z), tolerance);
  return inside > 0 ? std::min(1.0, static_cast<double>(voxels.size()) / inside) : 1.0;
}

namespace {

struct Cut {
  std::vector<Vec3i> a, b;
  double solidity = 0.0;
};

/// Joint solidity of the two parts: their voxels over the sum of their hulls' voxels.
double jointSolidity(const std::vector<Vec3i>& a, const std::vector<Vec3i>& b,
                     const GridSpec& grid) {
  const double hull_a = a.size() / voxelSolidity(a, grid);
  const double hull_b = b.size() / voxelSolidity(b, grid);
  return (a.size() + b.size()) / (hull_a + hull_b);
}

/// The most solid pair of parts among cuts across the grid axes and the principal axes at the
/// quantiles 0.15, 0.25, ..., 0.85; parts smaller than `min_voxels` are not considered.
Cut bestCut(const std::vector<Vec3i>& voxels, const GridSpec& grid, int min_voxels) {
  Cut best;
  const int n = static_cast<int>(voxels.size());
  if (n < 2 * std::max(min_voxels, 4)) return best;
  std::vector<Vec3> p(n);
  Vec3 mean = Vec3::Zero();
  for (int i = 0; i < n; ++i) {
    p[i] = voxels[i].cast<double>();
    mean += p[i];
  }
  mean /= n;
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (const Vec3& q : p) cov += (q - mean) * (q - mean).transpose();
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(cov);
  std::vector<Vec3> directions = {Vec3::UnitX(), Vec3::UnitY(), Vec3::UnitZ()};
  for (int k = 0; k < 3; ++k) directions.push_back(eig.eigenvectors().col(k));
  std::vector<int> order(n);
  std::vector<double> proj(n);
  for (const Vec3& d : directions) {
    for (int i = 0; i < n; ++i) proj[i] = d.dot(p[i]);
    std::iota(order.begin(), order.end(), 0);
    std::sort(order.begin(), order.end(), [&](int x, int y) { return proj[x] < proj[y]; });
    for (double q = 0.15; q < 0.9; q += 0.1) {
      // Cut between two distinct projections, so that voxels of one layer stay together.
      int m = static_cast<int>(q * n);
      while (m < n && m > 0 && proj[order[m]] - proj[order[m - 1]] < 1e-9) ++m;
      if (m < min_voxels || n - m < min_voxels) continue;
      Cut c;
      for (int i = 0; i < n; ++i) (i < m ? c.a : c.b).push_back(voxels[order[i]]);
      c.solidity = jointSolidity(c.a, c.b, grid);
      if (c.solidity > best.solidity) best = std::move(c);
    }
  }
  return best;
}

}  // namespace

int splitNonConvexInstances(InstanceSegmentation* seg, const HoughConfig& config) {
  if (config.experimental.split_below_solidity <= 0.0 || seg->size() == 0) return 0;
  const GridSpec& grid = seg->labels.spec;
  struct Part {
    std::vector<Vec3i> voxels;
    bool split = false;    ///< made by a cut (its centre is its centroid, not a Hough centre)
    bool settled = false;  ///< convex enough, or its best cut was refused: not tested again
    Vec3 centre = Vec3::Zero();
  };
  std::vector<Part> parts(seg->size());
  for (int k = 0; k < seg->size(); ++k) parts[k].centre = seg->centres_table[k];
  for (int i = 0; i < grid.voxelCount(); ++i)
    if (seg->labels.data[i] >= 0) parts[seg->labels.data[i]].voxels.push_back(grid.unravel(i));
  int splits = 0;
  for (int round = 0; round < config.experimental.split_max_rounds; ++round) {
    std::vector<Part> next;
    bool changed = false;
    for (Part& part : parts) {
      if (!part.settled &&
          voxelSolidity(part.voxels, grid) < config.experimental.split_below_solidity) {
        Cut c = bestCut(part.voxels, grid, config.min_instance_voxels);
        if (c.solidity >= config.experimental.split_accept_solidity) {
          next.push_back({std::move(c.a), true});
          next.push_back({std::move(c.b), true});
          ++splits;
          changed = true;
          continue;
        }
      }
      part.settled = true;
      next.push_back(std::move(part));
    }
    parts = std::move(next);
    if (!changed) break;
  }
  if (splits == 0) return 0;
  std::stable_sort(parts.begin(), parts.end(), [](const Part& a, const Part& b) {
    return a.voxels.size() > b.voxels.size();  // largest instance first
  });
  seg->centres_table.clear();
  seg->voxel_counts.clear();
  for (size_t k = 0; k < parts.size(); ++k) {
    Vec3 sum = Vec3::Zero();
    for (const Vec3i& v : parts[k].voxels) {
      seg->labels.at(v.x(), v.y(), v.z()) = static_cast<int>(k);
      sum += grid.voxelCentre(v.x(), v.y(), v.z());
    }
    seg->centres_table.push_back(parts[k].split ? sum / static_cast<double>(parts[k].voxels.size())
                                                : parts[k].centre);
    seg->voxel_counts.push_back(static_cast<int>(parts[k].voxels.size()));
  }
  return splits;
}

}  // namespace simstack
