#pragma once
/// @file mesh_ops.h
/// Small operations on triangle meshes shared by the perception and the evaluation: a mesh's
/// selected triangles, points sampled on it, and one mesh of several superquadrics.

#include <random>
#include <vector>

#include "simstack/geometry/superquadric.h"
#include "simstack/geometry/triangle_mesh.h"

namespace simstack {

/// The triangles with mask[i] set, as a mesh (vertices shared with the original).
TriangleMesh subMesh(const TriangleMesh& mesh, const std::vector<bool>& mask);

/// `count` area-weighted surface points (empty for an empty mesh).
Points3 samplePoints(const TriangleMesh& mesh, int count, std::mt19937_64& rng);

/// One closed mesh of all shapes (table frame).
TriangleMesh superquadricsMesh(const std::vector<SuperquadricShape>& shapes, int subdivisions = 16);

}  // namespace simstack
