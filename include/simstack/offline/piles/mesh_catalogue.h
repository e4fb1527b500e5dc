#pragma once
/// @file mesh_catalogue.h
/// Loading object meshes (e.g. the YCB objects of the paper's YCB test set) from disk.

#include <memory>
#include <string>
#include <vector>

#include "simstack/geometry/triangle_mesh.h"
#include "simstack/scene/scene.h"

namespace simstack {

/// Reads an STL, PLY or OBJ mesh in metres. Throws std::runtime_error naming the file when it
/// cannot be read or holds no triangles.
TriangleMesh loadMesh(const std::string& path);

/// Whether every name is a container's, so that the catalogue needs no mesh directory.
bool proceduralCatalogue(const std::vector<std::string>& names);

/// The YCB objects of the paper's YCB test set (IDs 2, 3, 4, 5, 7, 8, 9, 10, 36, 61).
const std::vector<std::string>& ycbObjectNames();

/// Loads `<dir>/<name>/nontextured.stl` for each name, in order (catalogue index = position);
/// a container's name (ContainerSpec::name) is built from its sizes instead, without `dir`.
/// Throws std::runtime_error naming the first missing or unreadable file.
std::vector<std::shared_ptr<const ObjectShape>> loadMeshCatalogue(
    const std::string& dir, const std::vector<std::string>& names = ycbObjectNames());

}  // namespace simstack
