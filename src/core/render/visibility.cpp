#include "simstack/render/visibility.h"

#include <cmath>

#include "simstack/render/depth_renderer.h"

namespace simstack {

std::vector<bool> visibleTriangles(const TriangleMesh& mesh, const PinholeCamera& camera,
                                   const Transform& T_table_camera) {
  std::vector<bool> visible(mesh.triangles.size(), false);
  if (mesh.empty()) return visible;
  const DepthRenderer caster(mesh);
  const Vec3 eye = T_table_camera.translation();
  const Transform T_camera_table = T_table_camera.inverse();
  for (size_t i = 0; i < mesh.triangles.size(); ++i) {
    const auto& t = mesh.triangles[i];
    const Vec3 c = (mesh.vertices[t[0]] + mesh.vertices[t[1]] + mesh.vertices[t[2]]) / 3.0;
    double u, v;
    // Pixel centres are whole numbers: the image spans [-0.5, size - 0.5).
    if (!camera.project(T_camera_table * c, &u, &v) || u < -0.5 || v < -0.5 ||
        u >= camera.width - 0.5 || v >= camera.height - 0.5)
      continue;
    int hit = -1;
    const double distance = caster.castRay(eye, c - eye, nullptr, &hit);
    // The triangle itself, or a hit within 1 mm of its centre (shared edges, float rounding).
    visible[i] = hit == static_cast<int>(i) || std::abs(distance - (c - eye).norm()) < 1e-3;
  }
  return visible;
}

}  // namespace simstack
