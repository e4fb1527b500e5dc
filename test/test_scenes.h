#pragma once
// Small analytic scenes shared by the unit tests.

#include "simstack/geometry/pinhole_camera.h"
#include "simstack/scene/scene.h"

namespace simstack {
namespace test {

/// One sphere (a superquadric with r = s = t = 2) of `radius` centred at `centre`.
inline Scene sphereScene(double radius, const Vec3& centre) {
  SuperquadricShape sq;
  sq.scale_m = Vec3::Constant(radius);
  SceneObject o;
  o.shape = ObjectShape::fromSuperquadric(sq);
  o.T_table_object.translation() = centre;
  return Scene{{o}};
}

/// A fixed four-object pile (a box carrying an ellipsoid, a standing cylinder and a rounded box
/// beside it) of 16 litres, the mean occupied volume of generated test piles: inputs for
/// benchmarks that must not change when the pile generator does.
inline Scene fourObjectPile() {
  auto object = [](const Vec3& half_m, const Vec3& exponents, const Vec3& centre, double yaw) {
    SuperquadricShape sq;
    sq.scale_m = half_m;
    sq.exponents = exponents;
    SceneObject o;
    o.shape = ObjectShape::fromSuperquadric(sq);
    o.T_table_object.linear() = Eigen::AngleAxisd(yaw, Vec3::UnitZ()).toRotationMatrix();
    o.T_table_object.translation() = centre;
    return o;
  };
  return Scene{{object({0.14, 0.11, 0.07}, {10, 10, 10}, {0.0, 0.0, 0.07}, 0.0),
                object({0.07, 0.07, 0.115}, {2, 2, 10}, {0.215, 0.03, 0.115}, 0.0),
                object({0.10, 0.07, 0.06}, {2, 2, 2}, {-0.03, 0.0, 0.20}, 0.5),
                object({0.07, 0.07, 0.07}, {4, 4, 4}, {-0.04, -0.203, 0.07}, 0.3)}};
}

/// A 1280x720 camera with a 90-degree horizontal field of view, as on an overhead pick station.
inline PinholeCamera wideCamera() {
  PinholeCamera c;
  c.width = 1280;
  c.height = 720;
  c.fx = c.fy = 640.0;
  c.cx = 639.5;
  c.cy = 359.5;
  return c;
}

}  // namespace test
}  // namespace simstack
