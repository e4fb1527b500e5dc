#pragma once
/// @file object_tracker.h
/// Ids that stay with an object from one perceived frame to the next, so that task code can
/// name a target once and find it again. Each new frame's objects are matched to the previous
/// frame's by their superquadric centres and sizes; a match keeps its id, an object without
/// one gets a new id, and the ids of objects that vanished are retired (never given again).
/// Objects left over by the centre gate are matched when each one's centre lies inside the
/// other's shape: two solids cannot hold each other's centres, but one object's estimates from
/// two views can lie further apart than the gate (a long flat object half hidden).

#include <cstdint>
#include <vector>

#include "simstack/geometry/superquadric.h"

namespace simstack {

struct TrackerConfig {
  /// Two objects of consecutive frames are one when their centres lie at most this far apart
  /// (m). The fit of a half-hidden object moves by up to 4 cm between views of a still pile
  /// (the example bag's camera circling it); a pick moves one by decimetres.
  double max_centre_distance_m = 0.05;
  /// ... and their semi-axes, each sorted by size, differ by at most this factor: the example
  /// bag's half-hidden flat box is fitted 3.3 times longer in one view than in the next.
  double max_size_ratio = 4.0;

  /// Throws std::invalid_argument naming the field unless both are finite, the distance > 0
  /// and the ratio >= 1.
  void validate() const;
};

class ObjectTracker {
 public:
  explicit ObjectTracker(const TrackerConfig& config = TrackerConfig());

  /// The ids of this frame's objects, in their order. Pairs within both gates are matched
  /// nearest centres first, each object at most once; then, nearest first, the pairs left whose
  /// shapes hold each other's centres, within the size gate.
  std::vector<uint32_t> assign(const std::vector<SuperquadricShape>& objects);
  /// Forgets the previous frame (a restarted bag, a cleared scene); ids keep counting up.
  void reset();
  const TrackerConfig& config() const { return config_; }

 private:
  struct Track {
    uint32_t id;
    SuperquadricShape shape;
    Vec3 centre;
    Vec3 sorted_axes;
  };
  TrackerConfig config_;
  std::vector<Track> previous_;
  uint32_t next_id_ = 0;
};

}  // namespace simstack
