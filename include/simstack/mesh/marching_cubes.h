#pragma once
/// @file marching_cubes.h
/// Surfaces from TSDF grids (VTK's flying-edges marching cubes), and their split by instance.

#include <vector>

#include "simstack/geometry/triangle_mesh.h"
#include "simstack/geometry/voxel_grid.h"

namespace simstack {

/// The zero level set of a TSDF (metres, positive outside) as a triangle mesh in the table
/// frame with outward (towards positive TSDF) triangles. The grid is padded with one layer of
/// free space, so objects touching the grid border or the table still give closed surfaces.
TriangleMesh extractSurface(const Grid3<float>& tsdf_m);

/// The instance of each triangle: the label of the voxel half a voxel behind the triangle's
/// centre, else the most common label among that voxel's 26 neighbours, else -1.
std::vector<int> triangleLabels(const TriangleMesh& mesh, const Grid3<int>& labels);

/// `count` meshes, the k-th holding the triangles labelled k (vertices re-indexed).
std::vector<TriangleMesh> splitByLabel(const TriangleMesh& mesh,
                                       const std::vector<int>& triangle_labels, int count);

}  // namespace simstack
