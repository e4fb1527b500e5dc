#pragma once
/// @file instance_finder.h
/// Instances of one scene hypothesis as the pipeline finds them: 3D Hough voting on the
/// network's vote field (hough_voting.h), then, given the first view's convex surface patches,
/// the regrouping along them (surface_segments.h), and a second split of a crowded pile.
/// ScenePerception and simstack_tune_hough both go through this class, so a tuned Hough
/// setting is scored as the product splits with it (the rules ScenePerception applies after
/// it, on the measured surface and the fits, are not scored).
/// Thread-safe: find() and segmentView() are const and keep no state.

#include <optional>

#include "simstack/instances/hough_voting.h"
#include "simstack/instances/surface_segments.h"

namespace simstack {

/// A second split for crowded piles: a hypothesis in which the first split finds `min_objects`
/// instances or more is split again with a smaller mean-shift radius, which keeps small
/// neighbours' centres apart (applied where they help: docs/experiments.md, "Instances: Hough
/// voting").
struct CrowdedConfig {
  int min_objects = 5;           ///< 0: off
  double bandwidth_m = 0.03;     ///< in place of hough.bandwidth_m
  int min_instance_voxels = 15;  ///< in place of hough.min_instance_voxels
  /// In place of segments.max_unseen_points (kept 0 where it is 0: several views reach the
  /// hypothesis).
  int max_unseen_points = 100;
  /// Throws std::invalid_argument naming the field ("crowded.bandwidth_m ...").
  void validate() const;
};

class InstanceFinder {
 public:
  /// Throws std::invalid_argument for a bad segment or crowded config value.
  InstanceFinder(const HoughConfig& hough, const SurfaceSegmentConfig& segments,
                 const CrowdedConfig& crowded = CrowdedConfig());

  /// The view's convex patches when the regrouping is enabled, std::nullopt otherwise.
  /// Points lower than `min_height_m` above the table, or outside `grid` when given, are left
  /// out.
  std::optional<SurfaceSegments> segmentView(const DepthImage& depth, const PinholeCamera& camera,
                                             const Transform& T_table_camera, double min_height_m,
                                             const GridSpec* grid = nullptr) const;

  /// Hough instances of `tsdf_m` / `votes` (one grid), regrouped along `segments` when given
  /// and the regrouping is enabled; found again with the crowded settings where they number
  /// crowded.min_objects or more.
  InstanceSegmentation find(const Grid3<float>& tsdf_m, const Grid3<Vec3f>& votes,
                            const SurfaceSegments* segments = nullptr) const;

  const HoughConfig& hough() const { return hough_; }
  const SurfaceSegmentConfig& segments() const { return segments_; }

 private:
  InstanceSegmentation findWith(const HoughConfig& hough, const SurfaceSegmentConfig& segments,
                                const Grid3<float>& tsdf_m, const Grid3<Vec3f>& votes,
                                const SurfaceSegments* patches) const;

  HoughConfig hough_;
  SurfaceSegmentConfig segments_;
  CrowdedConfig crowded_;
};

}  // namespace simstack
