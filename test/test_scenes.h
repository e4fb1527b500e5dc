#pragma once
// Small analytic scenes shared by the unit tests.

#include "simstack/scene/scene.h"

namespace simstack {
namespace test {

/// One sphere (a superquadric with r = s = t = 2) of `radius` centred at `centre`.
inline Scene sphereScene(double radius, const Vec3& centre) {
  Superquadric sq;
  sq.scale_m = Vec3::Constant(radius);
  SceneObject o;
  o.shape = ObjectShape::fromSuperquadric(sq);
  o.T_table_object.translation() = centre;
  return Scene{{o}};
}

}  // namespace test
}  // namespace simstack
