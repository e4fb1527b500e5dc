#pragma once
/// @file container.h
/// An open container (a bowl or a cup): a solid of revolution about z whose outer side is a
/// truncated cone from `radius_bottom_m` at z = 0 to `radius_top_m` at z = `height_m`, hollowed
/// from the top down to a floor `wall_m` thick, the side wall `wall_m` thick measured
/// horizontally. No superquadric can take this shape; training piles hold it so that the network
/// learns to complete concave objects.

#include <optional>
#include <string>

#include "simstack/geometry/triangle_mesh.h"
#include "simstack/types.h"

namespace simstack {

struct ContainerSpec {
  double radius_top_m = 0.06;
  double radius_bottom_m = 0.04;
  double height_m = 0.05;
  double wall_m = 0.005;

  /// Throws std::invalid_argument naming the field unless every size is finite and positive,
  /// the wall leaves a cavity (wall < both radii and < height) and the opening is at least 1 cm.
  void validate() const;
  /// Whether a point of the container's frame (base centre at the origin, axis z) is inside the
  /// solid: exact, the same surface as mesh().
  bool contains(const Vec3& p) const;
  /// Closed, outward-oriented mesh of the solid with `segments` facets around the axis.
  TriangleMesh mesh(int segments = 24) const;
  /// A name that holds the sizes to 0.1 mm ("container R_TOP R_BOTTOM HEIGHT WALL", metres), so
  /// that a dataset can name the shape and rebuild it (parseContainerName).
  std::string name() const;
};

/// The spec a name() encodes, or none when `name` is not a container's name.
std::optional<ContainerSpec> parseContainerName(const std::string& name);

}  // namespace simstack
