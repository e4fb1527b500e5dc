#include "simstack/geometry/container.h"

#include <cmath>
#include <cstdio>
#include <iomanip>
#include <locale>
#include <sstream>
#include <stdexcept>
#include <vector>

namespace simstack {
namespace {
constexpr char kPrefix[] = "container";
constexpr double kMinOpening_m = 0.01;
}  // namespace

void ContainerSpec::validate() const {
  const auto positive = [](double v, const char* field) {
    if (!(std::isfinite(v) && v > 0.0))
      throw std::invalid_argument(std::string("container ") + field +
                                  " must be finite and > 0, got " + std::to_string(v));
  };
  positive(radius_top_m, "radius_top_m");
  positive(radius_bottom_m, "radius_bottom_m");
  positive(height_m, "height_m");
  positive(wall_m, "wall_m");
  if (!(wall_m < height_m))
    throw std::invalid_argument("container wall_m (" + std::to_string(wall_m) +
                                ") must be below height_m (" + std::to_string(height_m) + ")");
  const double floor_radius =
      radius_bottom_m + (radius_top_m - radius_bottom_m) * wall_m / height_m - wall_m;
  if (!(radius_top_m - wall_m >= 0.5 * kMinOpening_m && floor_radius > 0.0))
    throw std::invalid_argument("container wall_m " + std::to_string(wall_m) +
                                " leaves no cavity in radii " + std::to_string(radius_top_m) +
                                " (top) and " + std::to_string(radius_bottom_m) + " (bottom)");
}

bool ContainerSpec::contains(const Vec3& p) const {
  if (p.z() < 0.0 || p.z() > height_m) return false;
  const double outer = radius_bottom_m + (radius_top_m - radius_bottom_m) * p.z() / height_m;
  const double r = std::hypot(p.x(), p.y());
  if (r > outer) return false;
  return p.z() <= wall_m || r >= outer - wall_m;
}

TriangleMesh ContainerSpec::mesh(int segments) const {
  validate();
  if (segments < 3) throw std::invalid_argument("container mesh needs >= 3 segments");
  const auto outer = [&](double z) {
    return radius_bottom_m + (radius_top_m - radius_bottom_m) * z / height_m;
  };
  // The cross-section, walked once around: base centre, base rim, top rim outside and inside,
  // floor rim, floor centre. Radius 0 marks the two poles on the axis.
  const std::vector<Vec2> profile = {{0.0, 0.0},
                                     {radius_bottom_m, 0.0},
                                     {radius_top_m, height_m},
                                     {radius_top_m - wall_m, height_m},
                                     {outer(wall_m) - wall_m, wall_m},
                                     {0.0, wall_m}};
  TriangleMesh m;
  std::vector<std::vector<int>> ring(profile.size());
  for (size_t i = 0; i < profile.size(); ++i) {
    const double r = profile[i].x(), z = profile[i].y();
    if (r == 0.0) {
      ring[i].assign(segments, static_cast<int>(m.vertices.size()));
      m.vertices.emplace_back(0.0, 0.0, z);
      continue;
    }
    for (int k = 0; k < segments; ++k) {
      const double a = 2.0 * M_PI * k / segments;
      ring[i].push_back(static_cast<int>(m.vertices.size()));
      m.vertices.emplace_back(r * std::cos(a), r * std::sin(a), z);
    }
  }
  for (size_t i = 0; i + 1 < profile.size(); ++i) {
    const std::vector<int>& a = ring[i];
    const std::vector<int>& b = ring[i + 1];
    for (int k = 0; k < segments; ++k) {
      const int k1 = (k + 1) % segments;
      if (a[k] != a[k1]) m.triangles.emplace_back(a[k], a[k1], b[k1]);
      if (b[k] != b[k1]) m.triangles.emplace_back(a[k], b[k1], b[k]);
    }
  }
  if (m.volume() < 0.0)
    for (auto& t : m.triangles) std::swap(t[1], t[2]);
  return m;
}

std::string ContainerSpec::name() const {
  // The classic locale both ways: a host program's decimal comma must not change the names.
  std::ostringstream text;
  text.imbue(std::locale::classic());
  text << kPrefix << std::fixed << std::setprecision(4) << ' ' << radius_top_m << ' '
       << radius_bottom_m << ' ' << height_m << ' ' << wall_m;
  return text.str();
}

std::optional<ContainerSpec> parseContainerName(const std::string& name) {
  std::istringstream in(name);
  in.imbue(std::locale::classic());
  std::string prefix;
  ContainerSpec spec;
  if (!(in >> prefix) || prefix != kPrefix) return std::nullopt;
  if (!(in >> spec.radius_top_m >> spec.radius_bottom_m >> spec.height_m >> spec.wall_m))
    return std::nullopt;
  std::string rest;
  if (in >> rest) return std::nullopt;
  try {
    spec.validate();
  } catch (const std::invalid_argument&) {
    return std::nullopt;
  }
  return spec;
}

}  // namespace simstack
