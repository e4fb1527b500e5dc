#pragma once
/// @file hough_tuning.h
/// Choosing a model's Hough-voting setting on validation piles (simstack_tune_hough). How sharp
/// a model's votes are decides which traversal threshold and mean-shift radius separate its
/// objects, so the setting belongs to the model (its card) and is chosen again whenever the
/// model changes. The network runs once per view; every setting is then scored on its grids
/// against the ground truth, as the pipeline decomposes (InstanceFinder): the share of views
/// whose instance count is exact first, then the voxel segmentation agreement.

#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "simstack/instances/surface_segments.h"
#include "simstack/offline/dataset/dataset.h"
#include "simstack/pipeline/perception_config.h"

namespace simstack {

/// The network's grids for one validation view and the ground truth on the same grid.
struct TuningView {
  Grid3<float> tsdf_m;
  Grid3<Vec3f> votes;
  std::vector<int> truth;  ///< object index per voxel, -1 free
  int objects = 0;
  std::optional<SurfaceSegments> segments;  ///< the view's convex patches, when regrouping
};

/// `views_per_scene` random noisy (or clean) 640x480 views of each of the first `scenes`
/// scenes (0 = all) through the model of `config`: hypothesis 0, the mean scene (zero code),
/// which the product decomposes. `progress(done, total)` after each scene.
std::vector<TuningView> tuningViews(const DatasetReader& reader, const PerceptionConfig& config,
                                    int scenes, int views_per_scene, uint64_t seed, bool noise,
                                    const std::function<void(int, int)>& progress = {});

/// The values tried for each field; every combination is a candidate.
struct HoughSweep {
  std::vector<int> refinements = {3, 5, 8, 10}, traversals = {2, 3, 4, 5, 7, 10},
                   min_voxels = {10, 15, 25};
  std::vector<double> bandwidths = {0.04, 0.05, 0.06, 0.07}, min_norms = {0.0, 0.3, 0.6};
};
/// `current` first, then every combination of `sweep` that differs from it (other fields of
/// `current` kept). Each runs on one thread (the settings run in parallel instead).
std::vector<HoughConfig> houghCandidates(const HoughConfig& current, const HoughSweep& sweep);

struct HoughScore {
  HoughConfig hough;
  double exact = 0, abs_error = 0, under = 0, over = 0, agreement = 0;  ///< over the views
};
/// The views' instances as InstanceFinder finds them with `hough` (then, where crowded, with
/// `crowded`'s settings), scored against the truth.
HoughScore scoreHoughSetting(const std::vector<TuningView>& views, const HoughConfig& hough,
                             const SurfaceSegmentConfig& segments, const CrowdedConfig& crowded);
/// Scores of every candidate, in their order, on `threads` threads. `progress(done, total)`.
std::vector<HoughScore> scoreHoughSettings(const std::vector<TuningView>& views,
                                           const std::vector<HoughConfig>& candidates,
                                           const SurfaceSegmentConfig& segments,
                                           const CrowdedConfig& crowded, int threads,
                                           const std::function<void(long, long)>& progress = {});
/// More views counted exactly; on a tie, the better voxel agreement.
bool betterHoughScore(const HoughScore& a, const HoughScore& b);
/// A table row (GitHub markdown) and the header it belongs under.
std::string houghScoreHeader();
std::string houghScoreRow(const HoughScore& s);

}  // namespace simstack
