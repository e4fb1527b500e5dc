#include "simstack/geometry/superquadric.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

namespace simstack {
namespace {

// log f(lambda * d) for f of eq. 4, as a log-sum-exp of the three terms; terms whose
// direction component is zero are skipped (log c = -inf).
struct RayTerms {
  double log_c[3];
  double e[3];
  bool used[3];
};

}  // namespace

double SuperquadricShape::insideOutsideObject(const Vec3& p) const {
  double f = 0.0;
  for (int i = 0; i < 3; ++i) f += std::pow(std::abs(p[i] / scale_m[i]), exponents[i]);
  return f;
}

double SuperquadricShape::insideOutside(const Vec3& p_table) const {
  return insideOutsideObject(T_table_object.inverse() * p_table);
}

Vec3 SuperquadricShape::surfacePointAlong(const Vec3& direction_object) const {
  // Solve f(lambda d) = 1. With u = log(lambda), h(u) = log sum_i c_i exp(e_i u) is convex and
  // increasing, so Newton started where h >= 0 decreases monotonically onto the root.
  RayTerms t;
  double u = -std::numeric_limits<double>::infinity();
  for (int i = 0; i < 3; ++i) {
    const double q = std::abs(direction_object[i] / scale_m[i]);
    t.used[i] = q > 0.0;
    t.e[i] = exponents[i];
    t.log_c[i] = t.used[i] ? exponents[i] * std::log(q) : 0.0;
    if (t.used[i]) u = std::max(u, -t.log_c[i] / t.e[i]);  // term i alone reaches 1 here
  }
  if (!std::isfinite(u)) return Vec3::Zero();
  for (int iter = 0; iter < 60; ++iter) {
    double m = -std::numeric_limits<double>::infinity();
    double z[3];
    for (int i = 0; i < 3; ++i) {
      z[i] = t.used[i] ? t.log_c[i] + t.e[i] * u : -std::numeric_limits<double>::infinity();
      m = std::max(m, z[i]);
    }
    double s = 0.0, ds = 0.0;
    for (int i = 0; i < 3; ++i) {
      if (!t.used[i]) continue;
      const double w = std::exp(z[i] - m);
      s += w;
      ds += t.e[i] * w;
    }
    const double h = m + std::log(s);
    const double dh = ds / s;
    const double step = h / dh;
    u -= step;
    if (std::abs(step) < 1e-13) break;
  }
  return std::exp(u) * direction_object;
}

Vec3 SuperquadricShape::normalObject(const Vec3& p) const {
  Vec3 g;
  for (int i = 0; i < 3; ++i) {
    const double q = std::abs(p[i] / scale_m[i]);
    const double s = p[i] >= 0.0 ? 1.0 : -1.0;
    g[i] = exponents[i] * std::pow(q, exponents[i] - 1.0) * s / scale_m[i];
  }
  const double n = g.norm();
  return n > 0.0 ? Vec3(g / n) : Vec3(p.normalized());
}

double SuperquadricShape::volume() const {
  const double r = 1.0 / exponents[0], s = 1.0 / exponents[1], t = 1.0 / exponents[2];
  return 8.0 * scale_m.prod() *
         std::exp(std::lgamma(1.0 + r) + std::lgamma(1.0 + s) + std::lgamma(1.0 + t) -
                  std::lgamma(1.0 + r + s + t));
}

TriangleMesh SuperquadricShape::meshObject(int n) const {
  // Six cube faces, each an (n+1)^2 vertex lattice; shared edge vertices are duplicated,
  // which keeps the code simple and does not change area, volume or rendering.
  TriangleMesh mesh;
  mesh.vertices.reserve(6 * (n + 1) * (n + 1));
  mesh.triangles.reserve(12 * n * n);
  for (int axis = 0; axis < 3; ++axis) {
    for (int sign = -1; sign <= 1; sign += 2) {
      const int a1 = (axis + 1) % 3, a2 = (axis + 2) % 3;
      const int base = static_cast<int>(mesh.vertices.size());
      for (int j = 0; j <= n; ++j) {
        for (int i = 0; i <= n; ++i) {
          Vec3 c;
          c[axis] = sign;
          c[a1] = -1.0 + 2.0 * i / n;
          c[a2] = -1.0 + 2.0 * j / n;
          mesh.vertices.push_back(surfacePointAlong(c.cwiseProduct(scale_m)));
        }
      }
      for (int j = 0; j < n; ++j) {
        for (int i = 0; i < n; ++i) {
          const int v00 = base + j * (n + 1) + i, v10 = v00 + 1, v01 = v00 + n + 1, v11 = v01 + 1;
          // (a1, a2, axis) is right-handed, so (i, j) counter-clockwise faces +axis.
          if (sign > 0) {
            mesh.triangles.emplace_back(v00, v10, v11);
            mesh.triangles.emplace_back(v00, v11, v01);
          } else {
            mesh.triangles.emplace_back(v00, v11, v10);
            mesh.triangles.emplace_back(v00, v01, v11);
          }
        }
      }
    }
  }
  return mesh;
}

std::vector<SurfacePoint> SuperquadricShape::sampleSurfaceObject(int count,
                                                                 std::mt19937_64& rng) const {
  std::vector<SurfacePoint> samples = meshObject(32).sampleSurface(count, rng);
  for (auto& s : samples) {
    s.position = surfacePointAlong(s.position);
    s.normal = normalObject(s.position);
  }
  return samples;
}

SuperquadricShape canonicalSuperquadric(const SuperquadricShape& sq) {
  std::array<int, 3> order{0, 1, 2};
  std::stable_sort(order.begin(), order.end(),
                   [&](int a, int b) { return sq.scale_m[a] > sq.scale_m[b]; });
  SuperquadricShape out = sq;
  const Mat3 R = sq.T_table_object.linear();
  Mat3 C;
  for (int k = 0; k < 3; ++k) {
    out.scale_m[k] = sq.scale_m[order[k]];
    out.exponents[k] = sq.exponents[order[k]];
    C.col(k) = R.col(order[k]);
  }
  // The solid is symmetric under each axis' reflection: a column's sign is free, so each is
  // chosen by its largest component, and the last one keeps the rotation proper (a reflection
  // of the third axis is a symmetry too).
  for (int k = 0; k < 2; ++k) {
    Eigen::Index top = 0;
    C.col(k).cwiseAbs().maxCoeff(&top);
    if (C(top, k) < 0) C.col(k) = -C.col(k);
  }
  C.col(2) = C.col(0).cross(C.col(1));
  out.T_table_object.linear() = C;
  return out;
}

namespace {
// Largest distance, along the ray from b's centre, of a's surface samples from b's surface.
double largestRayGap(const SuperquadricShape& a, const SuperquadricShape& b) {
  std::mt19937_64 rng(17);
  const Transform b_from_table = b.T_table_object.inverse();
  double worst = 0.0;
  for (const SurfacePoint& s : a.sampleSurfaceObject(2000, rng)) {
    const Vec3 p = b_from_table * (a.T_table_object * s.position);
    if (p.norm() < 1e-9) return std::numeric_limits<double>::infinity();
    worst = std::max(worst, std::abs(p.norm() - b.surfacePointAlong(p).norm()));
  }
  return worst;
}
}  // namespace

bool sameSuperquadric(const SuperquadricShape& a, const SuperquadricShape& b, double tolerance_m) {
  return largestRayGap(a, b) <= tolerance_m && largestRayGap(b, a) <= tolerance_m;
}

namespace {

/// The share of `small`'s volume inside `large` (sharedVolumeShare).
double shareOfFirstInside(const SuperquadricShape& small, const SuperquadricShape& large,
                          int samples) {
  if ((small.centroid() - large.centroid()).norm() >= small.scale_m.norm() + large.scale_m.norm() ||
      samples <= 0)
    return 0.0;
  // Rejection sampling in the smaller solid's box: a convex superquadric (exponents >= 1) fills
  // at least a sixth of it (the octahedron), so about six draws give one sample.
  std::mt19937_64 rng(0x5eed);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  int drawn = 0, inside = 0;
  for (int tries = 0; drawn < samples && tries < 20 * samples; ++tries) {
    const Vec3 p(unit(rng) * small.scale_m.x(), unit(rng) * small.scale_m.y(),
                 unit(rng) * small.scale_m.z());
    if (small.insideOutsideObject(p) >= 1.0) continue;
    ++drawn;
    if (large.contains(small.T_table_object * p)) ++inside;
  }
  return drawn > 0 ? static_cast<double>(inside) / drawn : 0.0;
}

}  // namespace

double sharedVolumeShare(const SuperquadricShape& a, const SuperquadricShape& b, int samples) {
  const double va = a.volume(), vb = b.volume();
  if (va < vb) return shareOfFirstInside(a, b, samples);
  if (vb < va) return shareOfFirstInside(b, a, samples);
  return std::max(shareOfFirstInside(a, b, samples), shareOfFirstInside(b, a, samples));
}

}  // namespace simstack
