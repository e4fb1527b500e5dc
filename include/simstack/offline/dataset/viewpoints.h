#pragma once
/// @file viewpoints.h
/// Random camera poses around a pile, for rendering training, evaluation and tuning views.

#include <random>

#include "simstack/types.h"

namespace simstack {

/// Ranges of random viewpoints (paper section 3.1.1 / 4.1): camera x, y relative to the scene
/// centre, camera height above the table, minimum camera-to-centre distance.
struct ViewpointRange {
  double lateral_min_m = -1.0;
  double lateral_max_m = 1.0;
  double height_min_m = 0.1;
  double height_max_m = 1.0;
  double min_distance_m = 0.5;
  /// Overhead views instead (elevation_max_deg > 0): the eye at a distance in [min_distance_m,
  /// max_distance_m] from the centre, an elevation in [elevation_min_deg, elevation_max_deg]
  /// (below 89) and any azimuth, as on a pick station's camera.
  double elevation_min_deg = 0.0, elevation_max_deg = 0.0;
  double max_distance_m = 1.0;

  /// The overhead range of a pick station: 60-89 degrees elevation, 0.6-1.0 m away.
  static ViewpointRange overhead();
};

/// A random T_table_camera in `range`, looking at `centre_table`.
Transform sampleViewpoint(const Vec3& centre_table, const ViewpointRange& range,
                          std::mt19937_64& rng);

}  // namespace simstack
