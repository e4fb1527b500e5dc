#include "simstack/geometry/pinhole_camera.h"

#include <cmath>
#include <sstream>
#include <stdexcept>

namespace simstack {

void PinholeCamera::validate() const {
  std::ostringstream err;
  if (width <= 0 || height <= 0) err << "image size " << width << "x" << height << " is empty; ";
  if (!(std::isfinite(fx) && fx > 0.0)) err << "fx = " << fx << " must be > 0; ";
  if (!(std::isfinite(fy) && fy > 0.0)) err << "fy = " << fy << " must be > 0; ";
  if (!std::isfinite(cx) || !std::isfinite(cy)) err << "principal point is not finite; ";
  if (!window) {
    // A camera's principal point lies near its image's centre; one beyond the middle half of
    // the image is another image size's (e.g. a 1280x720 camera's for a 640x360 image).
    const auto check_centre = [&](const char* name, double c, int side, const char* along) {
      if (std::isfinite(c) && std::abs(c - 0.5 * (side - 1)) >= 0.25 * side)
        err << name << " = " << c << " lies outside the middle half of the " << side << "-pixel-"
            << along << " image (intrinsics of another image size, or of a larger image this one "
            << "was cut from?); ";
    };
    // Zero or missing focal lengths (an unset K) say all there is to say.
    const bool focal_set = std::isfinite(fx) && fx > 0.0 && std::isfinite(fy) && fy > 0.0;
    if (focal_set) {
      check_centre("cx", cx, width, "wide");
      check_centre("cy", cy, height, "high");
    }
    // A focal length that gives a field of view outside 2-175 degrees is a unit mistake (e.g.
    // normalized intrinsics, or intrinsics of another image size).
    const auto fov_deg = [](double side, double f) {
      return 2.0 * std::atan(side / (2.0 * f)) * 180.0 / M_PI;
    };
    if (std::isfinite(fx) && fx > 0.0 && width > 0 &&
        (fov_deg(width, fx) < 2.0 || fov_deg(width, fx) > 175.0))
      err << "fx = " << fx << " gives a " << fov_deg(width, fx) << " degree field of view on "
          << width << " pixels (2-175 expected); ";
    if (std::isfinite(fy) && fy > 0.0 && height > 0 &&
        (fov_deg(height, fy) < 2.0 || fov_deg(height, fy) > 175.0))
      err << "fy = " << fy << " gives a " << fov_deg(height, fy) << " degree field of view on "
          << height << " pixels (2-175 expected); ";
  }
  const std::string s = err.str();
  if (!s.empty())
    throw std::invalid_argument("invalid camera intrinsics: " + s.substr(0, s.size() - 2));
}

PinholeCamera scaledKinect(int width, int height) {
  PinholeCamera c;
  const double s = width / 640.0;
  c.width = width;
  c.height = height;
  c.fx = 525.0 * s;
  c.fy = 525.0 * height / 480.0;
  c.cx = (width - 1) / 2.0;
  c.cy = (height - 1) / 2.0;
  return c;
}

Transform lookAt(const Vec3& eye_table, const Vec3& target_table) {
  const Vec3 z = (target_table - eye_table).normalized();
  Vec3 x = z.cross(Vec3::UnitZ());         // image x: to the right when table +z is up
  if (x.norm() < 1e-6) x = Vec3::UnitX();  // looking straight down or up
  x.normalize();
  const Vec3 y = z.cross(x);  // image y: down
  Transform T = Transform::Identity();
  T.linear().col(0) = x;
  T.linear().col(1) = y;
  T.linear().col(2) = z;
  T.translation() = eye_table;
  return T;
}

}  // namespace simstack
