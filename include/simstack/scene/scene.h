#pragma once
/// @file scene.h
/// A pile of rigid objects on the table (z = 0): shapes and their poses.

#include <memory>
#include <mutex>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "simstack/geometry/container.h"
#include "simstack/geometry/convex_hull.h"
#include "simstack/geometry/superquadric.h"
#include "simstack/geometry/triangle_mesh.h"
#include "simstack/types.h"

namespace simstack {

/// The shape of one object in its own frame (origin at its centroid). Immutable once built,
/// so one shape may be shared by many scenes and threads.
class ObjectShape {
 public:
  enum class Kind { kSuperquadric, kMesh };

  /// A superquadric shape; the pose of `sq` is ignored.
  static std::shared_ptr<const ObjectShape> fromSuperquadric(const SuperquadricShape& sq);
  /// A mesh shape (e.g. a YCB object), re-centred on its volume centroid. `catalogue_index`
  /// identifies the mesh in a dataset's mesh list. Throws std::invalid_argument for a mesh
  /// that encloses no volume.
  static std::shared_ptr<const ObjectShape> fromMesh(const std::string& name, int catalogue_index,
                                                     const TriangleMesh& mesh);
  /// An open container (a bowl or a cup) as a mesh shape named spec.name(), re-centred on its
  /// volume centroid; its inside test is the container's exact one. Throws
  /// std::invalid_argument for an invalid spec.
  static std::shared_ptr<const ObjectShape> fromContainer(const ContainerSpec& spec,
                                                          int catalogue_index);

  Kind kind() const { return kind_; }
  const std::string& name() const { return name_; }
  int catalogueIndex() const { return catalogue_index_; }
  /// SuperquadricShape parameters (pose = identity); only for Kind::kSuperquadric.
  const SuperquadricShape& superquadric() const { return superquadric_; }
  /// Render mesh, object frame.
  const TriangleMesh& mesh() const { return mesh_; }
  /// At most a few hundred points whose convex hull is the physics shape.
  const std::vector<Vec3>& hullPoints() const { return hull_points_; }
  /// Dense surface samples (about 4 mm apart) with outward normals; made on first use
  /// (thread-safe), since only ground truth and metrics need them.
  const std::vector<SurfacePoint>& surfaceSamples() const;
  /// Mean spacing of surfaceSamples() in metres.
  double sampleSpacing() const;
  /// Surface area (m^2) and area-weighted surface centroid (object frame) of the mesh.
  double surfaceArea() const { return area_m2_; }
  const Vec3& surfaceCentroidObject() const { return surface_centroid_; }
  /// Exact inside test for superquadrics and containers; convex-hull test for other meshes (the
  /// YCB objects used here are close to convex, and their scans have small holes that defeat
  /// parity tests).
  bool containsObject(const Vec3& p_object) const;
  double volume() const { return volume_; }
  /// Radius of the bounding sphere about the origin.
  double boundingRadius() const { return bounding_radius_; }

 private:
  ObjectShape() = default;
  static std::shared_ptr<ObjectShape> meshShape(const std::string& name, int catalogue_index,
                                                const TriangleMesh& mesh);
  void finish(uint64_t sample_seed);
  void makeSamples() const;

  Kind kind_ = Kind::kSuperquadric;
  std::string name_;
  int catalogue_index_ = -1;
  SuperquadricShape superquadric_;
  TriangleMesh mesh_;
  std::vector<Vec3> hull_points_;
  uint64_t sample_seed_ = 0;
  mutable std::once_flag samples_once_;
  mutable std::vector<SurfacePoint> samples_;
  std::optional<ConvexHull> hull_;
  std::optional<ContainerSpec> container_;
  Vec3 container_base_ = Vec3::Zero();  ///< the container's base centre, object frame
  mutable double sample_spacing_m_ = 0.004;
  double area_m2_ = 0.0;
  Vec3 surface_centroid_ = Vec3::Zero();
  double volume_ = 0.0;
  double bounding_radius_ = 0.0;
};

/// One object placed on the table.
struct SceneObject {
  std::shared_ptr<const ObjectShape> shape;
  Transform T_table_object = Transform::Identity();

  bool contains(const Vec3& p_table) const {
    return shape->containsObject(T_table_object.inverse() * p_table);
  }
  /// The object as a superquadric in the table frame (Kind::kSuperquadric only).
  SuperquadricShape superquadricTable() const {
    SuperquadricShape sq = shape->superquadric();
    sq.T_table_object = T_table_object;
    return sq;
  }
};

/// A pile: objects in the table frame, the table being the plane z = 0.
struct Scene {
  std::vector<SceneObject> objects;

  /// A scene of superquadrics given in the table frame (e.g. fitted shapes).
  static Scene fromSuperquadrics(const std::vector<SuperquadricShape>& shapes);

  /// Area-weighted centroid of all object surfaces: the x/y centre of the scene grid.
  Vec3 surfaceCentroid() const;
};

}  // namespace simstack
