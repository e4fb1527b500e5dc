#include "simstack/instances/instance_finder.h"

namespace simstack {

InstanceFinder::InstanceFinder(const HoughConfig& hough, const SurfaceSegmentConfig& segments)
    : hough_(hough), segments_(segments) {
  segments_.validate();
}

std::optional<SurfaceSegments> InstanceFinder::segmentView(const DepthImage& depth,
                                                           const PinholeCamera& camera,
                                                           const Transform& T_table_camera,
                                                           double min_height_m,
                                                           const GridSpec* grid) const {
  if (!segments_.enabled) return std::nullopt;
  return segmentVisibleSurface(depth, camera, T_table_camera, min_height_m, segments_, grid);
}

InstanceSegmentation InstanceFinder::find(const Grid3<float>& tsdf_m, const Grid3<Vec3f>& votes,
                                          const SurfaceSegments* segments) const {
  InstanceSegmentation seg = houghInstances(tsdf_m, votes, hough_);
  if (segments && segments_.enabled)
    seg =
        regroupAlongSurfaceSegments(*segments, segments_, hough_.min_instance_voxels, seg, &votes);
  return seg;
}

}  // namespace simstack
