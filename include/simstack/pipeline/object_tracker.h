#pragma once
/// @file object_tracker.h
/// Ids that stay with an object from one perceived frame to the next, so that task code can
/// name a target once and find it again. Each new frame's objects are matched to the previous
/// frame's by their superquadric centres and sizes; a match keeps its id, an object without
/// one gets a new id, and the ids of objects that vanished are retired (never given again).
/// Objects left over by the centre gate are matched when their shapes overlap: two solids share
/// no volume, but one object's estimates from two views can lie further apart than the gate (a
/// long flat object half hidden, estimated along its hidden length). An object a frame misses
/// (merged with a neighbour in one view, say) keeps its id for a few frames: found again within
/// them, near where it was last seen, it takes its id back.

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
  /// Two objects beyond the centre gate are one when at least this share of the smaller one's
  /// volume lies inside the other (sharedVolumeShare), within the size gate. Any two frames'
  /// estimates of the example bag's half-hidden box, up to 8 cm apart, share 43 % or more;
  /// neighbouring objects' estimates share none.
  double min_overlap_share = 0.3;
  /// An object missing from at most this many frames in a row is matched again, as it was last
  /// estimated; one missing from more is retired. 0: retired by the first frame without it.
  int max_missed_frames = 3;

  /// Throws std::invalid_argument naming the field unless the distance is finite and > 0, the
  /// ratio finite and >= 1, the overlap share in (0, 1] and max_missed_frames in [0, 1000].
  void validate() const;
};

class ObjectTracker {
 public:
  explicit ObjectTracker(const TrackerConfig& config = TrackerConfig());

  /// The ids of this frame's objects, in their order. Each is matched to an object of the
  /// previous frame or to one missed since (max_missed_frames): pairs within both gates
  /// nearest centres first, each object at most once; then, nearest first, the pairs left whose
  /// shapes overlap (min_overlap_share), within the size gate.
  std::vector<uint32_t> assign(const std::vector<SuperquadricShape>& objects);
  /// Forgets the previous frames (a restarted bag, a cleared scene); ids keep counting up.
  void reset();
  const TrackerConfig& config() const { return config_; }

 private:
  struct Track {
    uint32_t id;
    SuperquadricShape shape;
    Vec3 centre;
    Vec3 sorted_axes;
    int missed = 0;  ///< frames since it was last matched
  };
  TrackerConfig config_;
  std::vector<Track> previous_;
  uint32_t next_id_ = 0;
};

}  // namespace simstack
