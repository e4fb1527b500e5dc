#include "simstack/mesh/marching_cubes.h"

#include <vtkCellArray.h>
#include <vtkFloatArray.h>
#include <vtkFlyingEdges3D.h>
#include <vtkImageData.h>
#include <vtkNew.h>
#include <vtkPointData.h>
#include <vtkPolyData.h>

#include <map>
#include <stdexcept>
#include <unordered_map>

namespace simstack {

TriangleMesh extractSurface(const Grid3<float>& tsdf_m) {
  const GridSpec& g = tsdf_m.spec;
  if (static_cast<int>(tsdf_m.data.size()) != g.voxelCount())
    throw std::invalid_argument("extractSurface: grid data does not match its spec");
  const int r = g.resolution, p = r + 2;
  float outside = 0.0f;
  for (float v : tsdf_m.data) outside = std::max(outside, std::abs(v));
  outside = std::max(outside, static_cast<float>(g.voxel_size_m));

  vtkNew<vtkImageData> image;
  image->SetDimensions(p, p, p);
  image->SetSpacing(g.voxel_size_m, g.voxel_size_m, g.voxel_size_m);
  const Vec3 first = g.origin_table - Vec3::Constant(0.5 * g.voxel_size_m);  // padded centre 0
  image->SetOrigin(first.x(), first.y(), first.z());
  vtkNew<vtkFloatArray> values;
  values->SetNumberOfTuples(static_cast<vtkIdType>(p) * p * p);
  for (int z = 0; z < p; ++z)
    for (int y = 0; y < p; ++y)
      for (int x = 0; x < p; ++x) {
        const bool border = x == 0 || y == 0 || z == 0 || x == p - 1 || y == p - 1 || z == p - 1;
        const float v = border ? outside : tsdf_m.at(x - 1, y - 1, z - 1);
        values->SetValue((static_cast<vtkIdType>(z) * p + y) * p + x,
                         std::isfinite(v) ? v : outside);
      }
  image->GetPointData()->SetScalars(values);

  vtkNew<vtkFlyingEdges3D> mc;
  mc->SetInputData(image);
  mc->SetValue(0, 0.0);
  mc->ComputeNormalsOff();
  mc->ComputeGradientsOff();
  mc->ComputeScalarsOff();
  mc->Update();
  vtkPolyData* poly = mc->GetOutput();

  TriangleMesh mesh;
  mesh.vertices.resize(poly->GetNumberOfPoints());
  for (vtkIdType i = 0; i < poly->GetNumberOfPoints(); ++i) {
    double q[3];
    poly->GetPoint(i, q);
    mesh.vertices[i] = Vec3(q[0], q[1], q[2]);
  }
  vtkCellArray* polys = poly->GetPolys();
  mesh.triangles.reserve(polys->GetNumberOfCells());
  vtkNew<vtkIdList> ids;
  for (polys->InitTraversal(); polys->GetNextCell(ids);) {
    if (ids->GetNumberOfIds() != 3) continue;
    mesh.triangles.emplace_back(ids->GetId(0), ids->GetId(1), ids->GetId(2));
  }
  if (mesh.empty()) return mesh;

  // Orientation: normals must point up the TSDF gradient.
  double agreement = 0.0;
  const double eps = 0.25 * g.voxel_size_m;
  for (const auto& t : mesh.triangles) {
    const Vec3 a = mesh.vertices[t[0]], b = mesh.vertices[t[1]], c = mesh.vertices[t[2]];
    const Vec3 n = (b - a).cross(c - a);
    if (n.squaredNorm() <= 0) continue;
    const Vec3 centre = (a + b + c) / 3.0, u = n.normalized();
    agreement +=
        tsdf_m.sampleTrilinear(centre + eps * u) - tsdf_m.sampleTrilinear(centre - eps * u);
  }
  if (agreement < 0)
    for (auto& t : mesh.triangles) std::swap(t[1], t[2]);
  return mesh;
}

std::vector<int> triangleLabels(const TriangleMesh& mesh, const Grid3<int>& labels) {
  const GridSpec& g = labels.spec;
  std::vector<int> out(mesh.triangles.size(), -1);
  for (size_t i = 0; i < mesh.triangles.size(); ++i) {
    const auto& t = mesh.triangles[i];
    const Vec3 a = mesh.vertices[t[0]], b = mesh.vertices[t[1]], c = mesh.vertices[t[2]];
    Vec3 n = (b - a).cross(c - a);
    if (n.squaredNorm() > 0) n.normalize();
    const Vec3i v = g.voxelIndex((a + b + c) / 3.0 - 0.5 * g.voxel_size_m * n);
    if (g.inside(v.x(), v.y(), v.z()) && labels.at(v.x(), v.y(), v.z()) >= 0) {
      out[i] = labels.at(v.x(), v.y(), v.z());
      continue;
    }
    std::map<int, int> votes;
    for (int dz = -1; dz <= 1; ++dz)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          const int x = v.x() + dx, y = v.y() + dy, z = v.z() + dz;
          if (g.inside(x, y, z) && labels.at(x, y, z) >= 0) ++votes[labels.at(x, y, z)];
        }
    int best = 0;
    for (const auto& [label, count] : votes)
      if (count > best) {
        best = count;
        out[i] = label;
      }
  }
  return out;
}

std::vector<TriangleMesh> splitByLabel(const TriangleMesh& mesh,
                                       const std::vector<int>& triangle_labels, int count) {
  if (triangle_labels.size() != mesh.triangles.size())
    throw std::invalid_argument("splitByLabel: one label per triangle is required");
  std::vector<TriangleMesh> parts(std::max(count, 0));
  std::vector<std::unordered_map<int, int>> remap(parts.size());
  for (size_t i = 0; i < mesh.triangles.size(); ++i) {
    const int k = triangle_labels[i];
    if (k < 0 || k >= count) continue;
    Eigen::Vector3i tri;
    for (int j = 0; j < 3; ++j) {
      const int v = mesh.triangles[i][j];
      auto [it, fresh] = remap[k].try_emplace(v, static_cast<int>(parts[k].vertices.size()));
      if (fresh) parts[k].vertices.push_back(mesh.vertices[v]);
      tri[j] = it->second;
    }
    parts[k].triangles.push_back(tri);
  }
  return parts;
}

}  // namespace simstack
