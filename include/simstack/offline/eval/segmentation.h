#pragma once
/// @file segmentation.h
/// Agreement of an instance segmentation with labelled ground truth, for pixels (the real
/// mOSD scenes) or voxels (synthetic piles): true objects and found instances are matched one
/// to one, largest overlap first, and the agreement is the share of labelled elements whose
/// instance is the one matched to their object.
/// And the unseen-object segmentation literature's Overlap measures (UOIS-Net's multilabel
/// metrics, after Dave et al. 2019): objects and instances matched one to one by the
/// Hungarian method on their F-measure.

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

/// The one-to-one assignment of rows to columns of `weight` (rows x columns, any shape) with
/// the largest total weight (Hungarian method, O(n^3)): for each row its column, or -1 when
/// there are more rows than columns and the row is left out.
std::vector<int> maximumWeightAssignment(const std::vector<std::vector<double>>& weight);

struct OverlapScores {
  /// Matched elements over the elements of every instance (precision) and over those of
  /// every object (recall), and their harmonic mean.
  double precision = 0.0, recall = 0.0, f_measure = 0.0;
  /// Share of the objects whose matched instance has an F-measure above 0.75.
  double detected_075 = 0.0;
  int objects = 0;    ///< distinct true labels (>= 0)
  int instances = 0;  ///< distinct found labels (>= 0)
};

/// Overlap precision, recall and F of `found` against `truth` over the same elements (the
/// valid pixels of a view): truth < 0 is table or background, found < 0 no instance. Each
/// object is paired with at most one instance, maximising the summed per-pair F-measures.
/// With no objects and no instances every score is 1; with only one of them F is 0.
/// Throws std::invalid_argument when sizes differ.
OverlapScores overlapScores(const std::vector<int>& truth, const std::vector<int>& found);

}  // namespace simstack
