#include "simstack/mesh/mesh_ops.h"

namespace simstack {

TriangleMesh subMesh(const TriangleMesh& mesh, const std::vector<bool>& mask) {
  TriangleMesh out;
  out.vertices = mesh.vertices;
  for (size_t i = 0; i < mesh.triangles.size(); ++i)
    if (i < mask.size() && mask[i]) out.triangles.push_back(mesh.triangles[i]);
  return out;
}

Points3 samplePoints(const TriangleMesh& mesh, int count, std::mt19937_64& rng) {
  Points3 out;
  if (mesh.empty() || mesh.area() <= 0) return out;
  for (const SurfacePoint& s : mesh.sampleSurface(count, rng)) out.push_back(s.position);
  return out;
}

TriangleMesh superquadricsMesh(const std::vector<SuperquadricShape>& shapes, int subdivisions) {
  TriangleMesh all;
  for (const SuperquadricShape& sq : shapes)
    all.append(sq.meshObject(subdivisions).transformed(sq.T_table_object));
  return all;
}

}  // namespace simstack
