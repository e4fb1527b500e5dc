// Mesh files are read with PCL's VTK-based loader; PCL stays inside this translation unit.
#include "simstack/offline/piles/mesh_catalogue.h"

#include <pcl/PolygonMesh.h>
#include <pcl/conversions.h>
#include <pcl/io/vtk_lib_io.h>
#include <pcl/point_types.h>

#include <filesystem>
#include <stdexcept>

namespace simstack {

TriangleMesh loadMesh(const std::string& path) {
  if (!std::filesystem::exists(path)) throw std::runtime_error("mesh file not found: " + path);
  pcl::PolygonMesh poly;
  if (pcl::io::loadPolygonFile(path, poly) == 0 || poly.polygons.empty()) {
    throw std::runtime_error("cannot read a triangle mesh from " + path);
  }
  pcl::PointCloud<pcl::PointXYZ> cloud;
  pcl::fromPCLPointCloud2(poly.cloud, cloud);
  TriangleMesh mesh;
  mesh.vertices.reserve(cloud.size());
  for (const auto& p : cloud.points) mesh.vertices.emplace_back(p.x, p.y, p.z);
  for (const auto& poly_face : poly.polygons) {
    const auto& v = poly_face.vertices;
    for (size_t i = 1; i + 1 < v.size(); ++i) {  // fan-triangulate polygons
      mesh.triangles.emplace_back(v[0], v[i], v[i + 1]);
    }
  }
  if (mesh.triangles.empty()) throw std::runtime_error("mesh has no triangles: " + path);
  return mesh;
}

const std::vector<std::string>& ycbObjectNames() {
  static const std::vector<std::string> names = {
      "002_master_chef_can", "003_cracker_box", "004_sugar_box",   "005_tomato_soup_can",
      "007_tuna_fish_can",   "008_pudding_box", "009_gelatin_box", "010_potted_meat_can",
      "036_wood_block",      "061_foam_brick"};
  return names;
}

bool proceduralCatalogue(const std::vector<std::string>& names) {
  for (const std::string& name : names)
    if (!parseContainerName(name)) return false;
  return true;
}

std::vector<std::shared_ptr<const ObjectShape>> loadMeshCatalogue(
    const std::string& dir, const std::vector<std::string>& names) {
  std::vector<std::shared_ptr<const ObjectShape>> shapes;
  for (size_t i = 0; i < names.size(); ++i) {
    if (const auto container = parseContainerName(names[i])) {
      shapes.push_back(ObjectShape::fromContainer(*container, static_cast<int>(i)));
      continue;
    }
    const std::string path = dir + "/" + names[i] + "/nontextured.stl";
    shapes.push_back(ObjectShape::fromMesh(names[i], static_cast<int>(i), loadMesh(path)));
  }
  return shapes;
}

}  // namespace simstack
