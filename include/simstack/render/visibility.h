#pragma once
/// @file visibility.h
/// Which parts of a mesh a camera sees (Embree ray casts through the depth renderer).

#include <vector>

#include "simstack/geometry/pinhole_camera.h"
#include "simstack/geometry/triangle_mesh.h"

namespace simstack {

/// Triangles of `mesh` seen by the camera: the first surface hit by the ray from the camera
/// through the triangle's centre (Embree), with the centre inside the image.
std::vector<bool> visibleTriangles(const TriangleMesh& mesh, const PinholeCamera& camera,
                                   const Transform& T_table_camera);

}  // namespace simstack
