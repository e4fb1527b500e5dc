#include "simstack/instances/instance_finder.h"

#include <stdexcept>
#include <string>

namespace simstack {

void CrowdedConfig::validate() const {
  if (min_objects < 0 || min_objects > 255)
    throw std::invalid_argument("crowded.min_objects must lie in [0, 255] (0: off), not " +
                                std::to_string(min_objects));
  // A millimetre is far below a voxel, as hough.bandwidth_m's own lower bound.
  if (!(bandwidth_m >= 0.001 && bandwidth_m <= 1.0))
    throw std::invalid_argument("crowded.bandwidth_m must lie in [0.001, 1] m, not " +
                                std::to_string(bandwidth_m));
  if (min_instance_voxels < 1)
    throw std::invalid_argument("crowded.min_instance_voxels must be >= 1, not " +
                                std::to_string(min_instance_voxels));
  if (max_unseen_points < 0)
    throw std::invalid_argument("crowded.max_unseen_points must be >= 0, not " +
                                std::to_string(max_unseen_points));
}

InstanceFinder::InstanceFinder(const HoughConfig& hough, const SurfaceSegmentConfig& segments,
                               const CrowdedConfig& crowded)
    : hough_(hough), segments_(segments), crowded_(crowded) {
  segments_.validate();
  crowded_.validate();
}

std::optional<SurfaceSegments> InstanceFinder::segmentView(const DepthImage& depth,
                                                           const PinholeCamera& camera,
                                                           const Transform& T_table_camera,
                                                           double min_height_m,
                                                           const GridSpec* grid) const {
  if (!segments_.enabled) return std::nullopt;
  return segmentVisibleSurface(depth, camera, T_table_camera, min_height_m, segments_, grid);
}

InstanceSegmentation InstanceFinder::findWith(const HoughConfig& hough,
                                              const SurfaceSegmentConfig& segments,
                                              const Grid3<float>& tsdf_m, const Grid3<Vec3f>& votes,
                                              const SurfaceSegments* patches) const {
  InstanceSegmentation seg = houghInstances(tsdf_m, votes, hough);
  if (patches && segments.enabled)
    seg = regroupAlongSurfaceSegments(*patches, segments, hough.min_instance_voxels, seg, &votes);
  return seg;
}

InstanceSegmentation InstanceFinder::find(const Grid3<float>& tsdf_m, const Grid3<Vec3f>& votes,
                                          const SurfaceSegments* segments) const {
  InstanceSegmentation seg = findWith(hough_, segments_, tsdf_m, votes, segments);
  // A crowded pile split again with a smaller radius, unless those settings are the ones in
  // effect already.
  SurfaceSegmentConfig close_segments = segments_;
  if (close_segments.max_unseen_points > 0)
    close_segments.max_unseen_points = crowded_.max_unseen_points;
  HoughConfig close = hough_;
  close.bandwidth_m = crowded_.bandwidth_m;
  close.min_instance_voxels = crowded_.min_instance_voxels;
  const bool other_settings = close.bandwidth_m != hough_.bandwidth_m ||
                              close.min_instance_voxels != hough_.min_instance_voxels ||
                              close_segments.max_unseen_points != segments_.max_unseen_points;
  if (crowded_.min_objects > 0 && seg.size() >= crowded_.min_objects && other_settings)
    seg = findWith(close, close_segments, tsdf_m, votes, segments);
  return seg;
}

}  // namespace simstack
