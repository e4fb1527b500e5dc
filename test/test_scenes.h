#pragma once
// Small analytic scenes shared by the unit tests.

#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <string>
#include <system_error>
#include <vector>

#include "simstack/geometry/image.h"
#include "simstack/geometry/pinhole_camera.h"
#include "simstack/scene/scene.h"

namespace simstack {
namespace test {

/// The first of these files of ../shared/data (the third-party data) that is missing, or "": a
/// test that reads several of them skips, naming it, unless all are there.
inline std::string firstMissing(const std::vector<std::string>& paths) {
  for (const std::string& p : paths)
    if (!std::filesystem::exists(p)) return p;
  return {};
}

/// The mesh files of the YCB objects `names` under `dir`, as loadMeshCatalogue reads them.
inline std::vector<std::string> ycbMeshFiles(const std::string& dir,
                                             const std::vector<std::string>& names) {
  std::vector<std::string> out;
  for (const std::string& name : names) out.push_back(dir + "/" + name + "/nontextured.stl");
  return out;
}

/// `name` in a directory of this process's own under the temporary directory, so that two test
/// runs on one machine do not share files (the directory goes when the process ends).
inline std::filesystem::path tempPath(const std::string& name) {
  struct Directory {
    std::filesystem::path path =
        std::filesystem::temp_directory_path() / ("simstack_test_" + std::to_string(::getpid()));
    Directory() { std::filesystem::create_directories(path); }
    ~Directory() {
      std::error_code ec;
      std::filesystem::remove_all(path, ec);  // also what a test that stopped early left
    }
  };
  static const Directory directory;
  return directory.path / name;
}

/// The pixels where `pile` differs from `table` (the same view without the pile), widened by
/// `margin` and kept inside the image: [u0, u1] x [v0, v1]; u0 > u1 when none differ.
struct PixelBox {
  int u0, v0, u1, v1;
};
inline PixelBox pilePixels(const DepthImage& pile, const DepthImage& table, int margin) {
  PixelBox b{pile.width, pile.height, -1, -1};
  for (int v = 0; v < pile.height; ++v)
    for (int u = 0; u < pile.width; ++u)
      if (pile.at(u, v) != table.at(u, v))
        b = {std::min(b.u0, u), std::min(b.v0, v), std::max(b.u1, u), std::max(b.v1, v)};
  if (b.u0 > b.u1) return b;
  return {std::max(0, b.u0 - margin), std::max(0, b.v0 - margin),
          std::min(pile.width - 1, b.u1 + margin), std::min(pile.height - 1, b.v1 + margin)};
}

/// One sphere (a superquadric with r = s = t = 2) of `radius` centred at `centre`.
inline Scene sphereScene(double radius, const Vec3& centre) {
  SuperquadricShape sq;
  sq.scale_m = Vec3::Constant(radius);
  SceneObject o;
  o.shape = ObjectShape::fromSuperquadric(sq);
  o.T_table_object.translation() = centre;
  return Scene{{o}};
}

/// A fixed four-object pile (a box carrying an ellipsoid, a standing cylinder and a rounded box
/// beside it) of 16 litres, the mean occupied volume of generated test piles: inputs for
/// benchmarks that must not change when the pile generator does.
inline Scene fourObjectPile() {
  auto object = [](const Vec3& half_m, const Vec3& exponents, const Vec3& centre, double yaw) {
    SuperquadricShape sq;
    sq.scale_m = half_m;
    sq.exponents = exponents;
    SceneObject o;
    o.shape = ObjectShape::fromSuperquadric(sq);
    o.T_table_object.linear() = Eigen::AngleAxisd(yaw, Vec3::UnitZ()).toRotationMatrix();
    o.T_table_object.translation() = centre;
    return o;
  };
  return Scene{{object({0.14, 0.11, 0.07}, {10, 10, 10}, {0.0, 0.0, 0.07}, 0.0),
                object({0.07, 0.07, 0.115}, {2, 2, 10}, {0.215, 0.03, 0.115}, 0.0),
                object({0.10, 0.07, 0.06}, {2, 2, 2}, {-0.03, 0.0, 0.20}, 0.5),
                object({0.07, 0.07, 0.07}, {4, 4, 4}, {-0.04, -0.203, 0.07}, 0.3)}};
}

/// A width x height camera with square pixels of focal length `focal_px` and the principal point
/// at the image centre.
inline PinholeCamera centredCamera(int width, int height, double focal_px) {
  PinholeCamera c;
  c.width = width;
  c.height = height;
  c.fx = c.fy = focal_px;
  c.cx = 0.5 * (width - 1);
  c.cy = 0.5 * (height - 1);
  return c;
}

/// A 1280x720 camera with a 90-degree horizontal field of view, as on an overhead pick station.
inline PinholeCamera wideCamera() { return centredCamera(1280, 720, 640.0); }

}  // namespace test
}  // namespace simstack
