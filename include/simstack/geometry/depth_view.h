#pragma once
/// @file depth_view.h
/// One depth image with its camera and, when known, its pose in the table frame.

#include <optional>

#include "simstack/geometry/image.h"
#include "simstack/geometry/pinhole_camera.h"
#include "simstack/types.h"

namespace simstack {

struct DepthView {
  DepthImage depth;  ///< metres; NaN / 0 = missing
  PinholeCamera camera;
  std::optional<Transform> T_table_camera;  ///< unknown: the table is estimated from the depth
  /// Optional, the depth's size: pixels where it is 0 are ignored (not the workspace); empty:
  /// every pixel counts.
  Image<uint8_t> mask = {};
};

}  // namespace simstack
