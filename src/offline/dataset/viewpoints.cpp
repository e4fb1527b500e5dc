#include "simstack/offline/dataset/viewpoints.h"

#include <cmath>
#include <stdexcept>

#include "simstack/geometry/pinhole_camera.h"

namespace simstack {

ViewpointRange ViewpointRange::overhead() {
  ViewpointRange r;
  r.elevation_min_deg = 60.0;
  r.elevation_max_deg = 89.0;
  r.min_distance_m = 0.6;
  r.max_distance_m = 1.0;
  return r;
}

Transform sampleViewpoint(const Vec3& centre_table, const ViewpointRange& range,
                          std::mt19937_64& rng) {
  if (range.elevation_max_deg > 0.0) {
    if (!(range.elevation_min_deg <= range.elevation_max_deg && range.elevation_max_deg < 89.5 &&
          range.min_distance_m > 0.0 && range.min_distance_m <= range.max_distance_m))
      throw std::invalid_argument(
          "viewpoint range: need elevations min <= max < 89.5 degrees and "
          "distances 0 < min <= max");
    std::uniform_real_distribution<double> azimuth(0.0, 2.0 * M_PI);
    std::uniform_real_distribution<double> elevation(range.elevation_min_deg * M_PI / 180.0,
                                                     range.elevation_max_deg * M_PI / 180.0);
    std::uniform_real_distribution<double> distance(range.min_distance_m, range.max_distance_m);
    const double a = azimuth(rng), e = elevation(rng), d = distance(rng);
    const Vec3 eye =
        centre_table + d * Vec3(std::cos(e) * std::cos(a), std::cos(e) * std::sin(a), std::sin(e));
    return lookAt(eye, centre_table);
  }
  std::uniform_real_distribution<double> lateral(range.lateral_min_m, range.lateral_max_m);
  std::uniform_real_distribution<double> height(range.height_min_m, range.height_max_m);
  for (int attempt = 0; attempt < 10000; ++attempt) {
    const Vec3 eye(centre_table.x() + lateral(rng), centre_table.y() + lateral(rng), height(rng));
    const double dist = (eye - centre_table).norm();
    if (dist < range.min_distance_m) continue;
    // Keep away from looking straight down, where lookAt's "up" is undefined.
    if ((eye - centre_table).head<2>().norm() < 1e-3) continue;
    return lookAt(eye, centre_table);
  }
  throw std::invalid_argument("viewpoint range admits no camera at the minimum distance");
}

}  // namespace simstack
