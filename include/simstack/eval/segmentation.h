#pragma once
/// @file segmentation.h
/// Agreement of an instance segmentation with labelled ground truth, for pixels (the real
/// mOSD scenes) or voxels (synthetic piles): true objects and found instances are matched one
/// to one, largest overlap first, and the agreement is the share of labelled elements whose
/// instance is the one matched to their object.

#include <vector>

namespace simstack {

struct SegmentationAgreement {
  double agreement = 0.0;  ///< matched labelled elements / labelled elements (0 when none)
  int objects = 0;         ///< distinct true labels (>= 0)
  int instances = 0;       ///< distinct found labels (>= 0) among all elements
};

/// `truth` and `found` label the same elements; truth < 0 is not labelled (not counted),
/// found < 0 is assigned to no instance. Throws std::invalid_argument when sizes differ.
SegmentationAgreement segmentationAgreement(const std::vector<int>& truth,
                                            const std::vector<int>& found);

}  // namespace simstack
