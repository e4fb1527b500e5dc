#pragma once
/// @file occupancy.h
/// Expected-occupancy scores of the paper's section 4.1 (eq. 8 and IoU at 0.5).

#include <vector>

namespace simstack {

struct OccupancyScores {
  double bce = 0.0;  ///< eq. 8, natural log, probabilities clamped to [1e-3, 1 - 1e-3]
  double iou = 0.0;  ///< of (mean occupancy > 0.5) against the ground truth
};

/// Occupancy is tsdf <= 0. `samples` are S predicted TSDFs of the ground truth's size (any
/// consistent unit). Throws std::invalid_argument on size mismatch or no samples.
OccupancyScores scoreOccupancy(const std::vector<float>& ground_truth_tsdf,
                               const std::vector<std::vector<float>>& samples);

}  // namespace simstack
