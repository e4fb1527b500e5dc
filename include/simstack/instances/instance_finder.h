#pragma once
/// @file instance_finder.h
/// Instances of one scene hypothesis as the pipeline finds them: 3D Hough voting on the
/// network's vote field (hough_voting.h), then, given the first view's convex surface patches,
/// the regrouping along them (surface_segments.h). ScenePerception and simstack_tune_hough both
/// go through this class, so a tuned setting is scored exactly as the product uses it.
/// Thread-safe: find() and segmentView() are const and keep no state.

#include <optional>

#include "simstack/instances/hough_voting.h"
#include "simstack/instances/surface_segments.h"

namespace simstack {

class InstanceFinder {
 public:
  /// Throws std::invalid_argument for a bad segment config value.
  InstanceFinder(const HoughConfig& hough, const SurfaceSegmentConfig& segments);

  /// The view's convex patches when the regrouping is enabled, std::nullopt otherwise.
  /// Points lower than `min_height_m` above the table, or outside `grid` when given, are left
  /// out.
  std::optional<SurfaceSegments> segmentView(const DepthImage& depth, const PinholeCamera& camera,
                                             const Transform& T_table_camera, double min_height_m,
                                             const GridSpec* grid = nullptr) const;

  /// Hough instances of `tsdf_m` / `votes` (one grid), regrouped along `segments` when given
  /// and the regrouping is enabled.
  InstanceSegmentation find(const Grid3<float>& tsdf_m, const Grid3<Vec3f>& votes,
                            const SurfaceSegments* segments = nullptr) const;

  const HoughConfig& hough() const { return hough_; }
  const SurfaceSegmentConfig& segments() const { return segments_; }

 private:
  HoughConfig hough_;
  SurfaceSegmentConfig segments_;
};

}  // namespace simstack
