#pragma once
/// @file hough_voting.h
/// Class-agnostic instances from the network's centre-vote field (paper section 3.2.1).
/// Every occupied voxel casts a ray along its vote; the ray is marched through a grid
/// `refinement` times finer than the scene grid and stops where the TSDF says the object ends.
/// Fine cells crossed by more than `min_traversals` rays are centre votes; mean shift merges
/// them into centres, and each occupied voxel joins the centre minimising
///   |arccos(v . u_n)| + gamma * d_n / voxel_size,
/// with v its vote, u_n the unit vector towards centre n and d_n the distance to it.
/// Counting is sparse: only the fine cells of occupied voxels are counted, never a dense fine
/// grid. Memory: threads x occupied voxels x ref^3 x 2 bytes (16-bit counts that saturate at
/// 65535 per thread; the threads' counts are summed in 32 bits); 7.8 MB for a 4-object pile at
/// R = 64, ref = 5, 2 threads.

#include <vector>

#include "simstack/geometry/voxel_grid.h"

namespace simstack {

/// Fine cells along a grid's side (resolution x refinement) at most: they are counted with
/// 32-bit indices (1625^3 < 2^32).
constexpr int kMaxHoughFineCells = 1625;

struct HoughConfig {
  int refinement = 5;         ///< fine cells per voxel along each axis (the paper: 10)
  int min_traversals = 4;     ///< mu: a fine cell with more traversals is a centre vote (paper: 10)
  double gamma = 0.1;         ///< weight of the distance (in voxels) in the assignment rule
  double bandwidth_m = 0.05;  ///< mean-shift radius (flat kernel)
  int min_instance_voxels = 15;  ///< smaller instances are dropped (their voxels re-assigned)
  /// Votes shorter than this cast no ray (the network shrinks votes it is unsure of); their
  /// voxels are still assigned, by distance alone.
  double min_vote_norm = 0.0;
  /// Rays may leave the occupied region for this many voxels (noisy TSDF borders).
  int outside_tolerance_vox = 1;
  int threads = 2;
  void validate() const;  ///< std::invalid_argument naming the field and its bad value
};

struct InstanceSegmentation {
  std::vector<Vec3> centres_table;  ///< one per instance, table frame
  Grid3<int> labels;                ///< instance index per voxel, -1 = free space / none
  std::vector<int> voxel_counts;    ///< occupied voxels per instance
  int candidate_cells = 0;          ///< fine cells above the traversal threshold
  size_t count_bytes = 0;           ///< memory of the fine counts (all threads)
  size_t traversals = 0;            ///< fine-cell visits counted (all rays)
  struct {
    double rays_ms = 0, mean_shift_ms = 0, assign_ms = 0;
  } timings;
  int size() const { return static_cast<int>(centres_table.size()); }
};

/// More vote centres than kMaxHoughCentres: a mean-shift radius far below the votes' spread
/// (assigning every voxel to thousands of centres would take minutes per frame).
constexpr size_t kMaxHoughCentres = 1000;
struct TooManyHoughCentres : std::invalid_argument {
  using std::invalid_argument::invalid_argument;
};

/// Instances of one scene hypothesis. `tsdf_m` and `votes` must share a grid
/// (std::invalid_argument otherwise); occupied = tsdf <= 0. Votes need not be unit length
/// (the network's are normalised here); short votes are assigned by distance alone.
/// TooManyHoughCentres where the radius makes more than kMaxHoughCentres centres.
InstanceSegmentation houghInstances(const Grid3<float>& tsdf_m, const Grid3<Vec3f>& votes,
                                    const HoughConfig& config = HoughConfig());

}  // namespace simstack
