#include "simstack/grasping/suction_candidates.h"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <random>
#include <stdexcept>
#include <tuple>
#include <utility>

#include "simstack/render/depth_renderer.h"
#include "simstack/scene/scene.h"

namespace simstack {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

// log f of eq. 4 at an object-frame point: finite far outside, where f itself overflows for
// box-like exponents, and monotone in f, so the line searches below can compare it.
double logInsideOutside(const SuperquadricShape& sq, const Vec3& p) {
  double terms[3], m = -kInf;
  for (int i = 0; i < 3; ++i) {
    const double q = std::max(std::abs(p[i] / sq.scale_m[i]), 1e-300);
    terms[i] = sq.exponents[i] * std::log(q);
    m = std::max(m, terms[i]);
  }
  double s = 0.0;
  for (double t : terms) s += std::exp(t - m);
  return m + std::log(s);
}

Vec3 perpendicular(const Vec3& a) {
  const Vec3 helper = std::abs(a.x()) < 0.9 ? Vec3::UnitX() : Vec3::UnitY();
  return a.cross(helper).normalized();
}

bool seenFromAny(const DepthRenderer& renderer, int instance, const Vec3& p, const Vec3& normal,
                 const std::vector<Vec3>& cameras) {
  // The renderer meshes each superquadric with flat facets inside its exact surface; a point
  // of the exact surface counts as seen when the ray towards it hits this object no more than
  // this much before reaching it.
  constexpr double kFacetTolerance_m = 0.004;
  for (const Vec3& c : cameras) {
    const Vec3 d = p - c;
    const double range = d.norm();
    if (!(range > 1e-6) || d.dot(normal) >= 0.0) continue;  // behind the surface
    int hit = -1;
    const double t = renderer.castRay(c, d / range, &hit);
    if (hit == instance && t >= range - kFacetTolerance_m) return true;
  }
  return false;
}

// Farthest-point spread, `count` in all: the first `seeds` candidates kept first (a repeated
// point once), then the candidate farthest from those kept, starting from the best seal when
// there are no seeds (ties to the lower index, so the result is deterministic).
std::vector<SuctionCandidate> spread(const std::vector<SuctionCandidate>& all, int count,
                                     size_t seeds) {
  std::vector<SuctionCandidate> kept;
  if (all.empty() || count <= 0) return kept;
  std::vector<double> nearest(all.size(), kInf);
  const auto keep = [&](size_t k) {
    kept.push_back(all[k]);
    for (size_t i = 0; i < all.size(); ++i)
      nearest[i] = std::min(nearest[i], (all[i].contact_table - all[k].contact_table).norm());
  };
  for (size_t k = 0; k < std::min(seeds, all.size()) && static_cast<int>(kept.size()) < count; ++k)
    if (nearest[k] > 0.0) keep(k);
  if (static_cast<int>(kept.size()) >= count) return kept;
  size_t first = 0;
  if (kept.empty()) {
    for (size_t i = 1; i < all.size(); ++i)
      if (all[i].seal_score > all[first].seal_score) first = i;
  } else {  // on from the point farthest from the seeds
    first = static_cast<size_t>(std::max_element(nearest.begin(), nearest.end()) - nearest.begin());
  }
  if (nearest[first] <= 0.0) return kept;
  size_t next = first;
  while (static_cast<int>(kept.size()) < count) {
    const Vec3 added = all[next].contact_table;
    kept.push_back(all[next]);
    double best = 0.0;
    for (size_t i = 0; i < all.size(); ++i) {
      nearest[i] = std::min(nearest[i], (all[i].contact_table - added).norm());
      if (nearest[i] > best) {
        best = nearest[i];
        next = i;
      }
    }
    if (best <= 0.0) break;  // every point kept
  }
  return kept;
}

/// Surface points (object frame) whose pull along the normal passes through the centre of
/// mass or near it, where the load's moment on the seal is least: on each of the six ends of the
/// object's axes, the point on the axis, four a cup's radius around it and eight two radii
/// around it (a face wider than the cup then offers a patch of holding grasps, not one point).
/// The six ends first, then the rings, each in the order of the ends from the most upward
/// (table frame): a spread of few candidates keeps the upper faces' middles, which the ranking
/// puts first, not those of the axes listed first.
std::vector<SurfacePoint> centredSamples(const SuperquadricShape& sq, double cup_radius_m) {
  std::vector<std::pair<int, double>> ends;  // axis, sign
  for (int axis = 0; axis < 3; ++axis)
    for (double sign : {1.0, -1.0}) ends.emplace_back(axis, sign);
  const Mat3 R = sq.T_table_object.linear();
  const auto upward = [&](const std::pair<int, double>& e) {
    return e.second * R(2, e.first);  // the end's direction, its z in the table frame
  };
  std::stable_sort(ends.begin(), ends.end(),
                   [&](const auto& a, const auto& b) { return upward(a) > upward(b); });
  std::vector<Vec3> towards;
  for (const auto& [axis, sign] : ends) towards.push_back(sign * Vec3::Unit(axis));
  for (const auto& [axis, sign] : ends) {
    const Vec3 end = sq.surfacePointAlong(sign * Vec3::Unit(axis));
    for (int other = 0; other < 3; ++other)
      if (other != axis)
        for (double side : {1.0, -1.0})
          towards.push_back(end + side * cup_radius_m * Vec3::Unit(other));
  }
  for (const auto& [axis, sign] : ends) {
    const Vec3 end = sq.surfacePointAlong(sign * Vec3::Unit(axis));
    const Vec3 u = Vec3::Unit((axis + 1) % 3), v = Vec3::Unit((axis + 2) % 3);
    for (int k = 0; k < 8; ++k) {
      const double phi = M_PI / 4.0 * k;
      towards.push_back(end + 2.0 * cup_radius_m * (std::cos(phi) * u + std::sin(phi) * v));
    }
  }
  std::vector<SurfacePoint> out;
  for (const Vec3& t : towards) {
    SurfacePoint p;
    p.position = sq.surfacePointAlong(t.normalized());
    p.normal = sq.normalObject(p.position).normalized();
    if (p.position.allFinite() && p.normal.allFinite()) out.push_back(p);
  }
  return out;
}

void validate(const std::vector<SuperquadricShape>& scene, int target,
              const CandidateConfig& config) {
  if (target < 0 || target >= static_cast<int>(scene.size()))
    throw std::invalid_argument("target " + std::to_string(target) + " is not an object of the " +
                                std::to_string(scene.size()) + "-object scene");
  if (!(config.cup_radius_m > 0.0) || !std::isfinite(config.cup_radius_m))
    throw std::invalid_argument("cup_radius_m must be > 0");
  if (!(config.seal_tolerance_m > 0.0) || !std::isfinite(config.seal_tolerance_m))
    throw std::invalid_argument("seal_tolerance_m must be > 0");
  if (config.rim_points < 3) throw std::invalid_argument("rim_points must be >= 3");
  if (config.surface_samples < 1) throw std::invalid_argument("surface_samples must be >= 1");
  if (!std::isfinite(config.tool_length_m) || config.tool_length_m < 0.0)
    throw std::invalid_argument("tool_length_m must be >= 0");
}

}  // namespace

std::vector<Vec3> defaultCameraPositions(const std::vector<SuperquadricShape>& scene,
                                         double distance_m) {
  Vec3 centre = Vec3::Zero();
  for (const SuperquadricShape& sq : scene) centre += sq.centroid();
  if (!scene.empty()) centre /= static_cast<double>(scene.size());
  centre.z() = 0.0;
  std::vector<Vec3> cameras{centre + Vec3(0, 0, distance_m)};
  const double s = distance_m * std::sqrt(0.5);
  for (int k = 0; k < 4; ++k) {
    const double yaw = k * M_PI / 2.0;
    cameras.push_back(centre + Vec3(s * std::cos(yaw), s * std::sin(yaw), s));
  }
  return cameras;
}

std::optional<Vec3> enterSuperquadric(const SuperquadricShape& sq, const Vec3& origin,
                                      const Vec3& direction, double max_distance_m) {
  const Transform T_object_table = sq.T_table_object.inverse();
  const Vec3 o = T_object_table * origin;
  const Vec3 d = T_object_table.linear() * direction.normalized();
  const auto h = [&](double t) { return logInsideOutside(sq, o + t * d); };
  if (h(0.0) <= 0.0) return origin;
  // Golden-section search for the line's deepest point (log f is unimodal along a line
  // through a convex superquadric), then bisection for the entry between 0 and it.
  const double g = (std::sqrt(5.0) - 1.0) / 2.0;
  double a = 0.0, b = max_distance_m;
  double c = b - g * (b - a), e = a + g * (b - a), hc = h(c), he = h(e);
  for (int i = 0; i < 60; ++i) {
    if (hc < he) {
      b = e, e = c, he = hc, c = b - g * (b - a), hc = h(c);
    } else {
      a = c, c = e, hc = he, e = a + g * (b - a), he = h(e);
    }
  }
  double lo = 0.0, hi = 0.5 * (a + b);
  if (h(hi) > 0.0) return std::nullopt;
  for (int i = 0; i < 50; ++i) {
    const double mid = 0.5 * (lo + hi);
    (h(mid) > 0.0 ? lo : hi) = mid;
  }
  return origin + hi * direction.normalized();
}

double rimDeviation(const SuperquadricShape& sq, const Vec3& contact, const Vec3& approach,
                    double cup_radius_m, int rim_points, double limit_m) {
  const Vec3 a = approach.normalized();
  const Vec3 u = perpendicular(a), v = a.cross(u);
  const Transform T_object_table = sq.T_table_object.inverse();
  const Vec3 a_object = T_object_table.linear() * a;
  // Each rim point is searched for along -a from just above the cup's plane down to the
  // limit. The object is convex and lies below its tangent plane, so the rim point is outside
  // at the start; inside at the limit, or at a step before it (a plate thinner than the
  // search), means it lands within it, found by bisection.
  constexpr int kPlateSteps = 16;
  const double lift = 0.001, reach = lift + std::min(limit_m, 2.0 * cup_radius_m);
  double worst = 0.0;
  for (int k = 0; k < rim_points; ++k) {
    const double phi = 2.0 * M_PI * k / rim_points;
    const Vec3 rim = contact + cup_radius_m * (std::cos(phi) * u + std::sin(phi) * v);
    const Vec3 o = T_object_table * (rim + lift * a);
    const auto h = [&](double t) { return logInsideOutside(sq, o - t * a_object); };
    double lo = 0.0, hi = reach;
    if (h(0.0) <= 0.0) {
      hi = 0.0;
    } else if (h(reach) > 0.0) {
      hi = kInf;
      for (int step = 1; step < kPlateSteps && hi == kInf; ++step) {
        const double t = reach * step / kPlateSteps;
        (h(t) > 0.0 ? lo : hi) = t;
      }
      if (hi == kInf) return kInf;  // the rim misses the object
    }
    for (int i = 0; i < 30 && hi > 0.0; ++i) {
      const double mid = 0.5 * (lo + hi);
      (h(mid) > 0.0 ? lo : hi) = mid;
    }
    worst = std::max(worst, std::abs(hi - lift));
  }
  return worst;
}

namespace {

/// The least-squares plane of `points`: their centroid and the normal on the side of `side`.
std::pair<Vec3, Vec3> fitPlane(const Points3& points, const Vec3& side) {
  Vec3 centre = Vec3::Zero();
  for (const Vec3& p : points) centre += p;
  centre /= static_cast<double>(points.size());
  Mat3 cov = Mat3::Zero();
  for (const Vec3& p : points) cov += (p - centre) * (p - centre).transpose();
  const Eigen::SelfAdjointEigenSolver<Mat3> eig(cov);
  Vec3 n = eig.eigenvectors().col(0);  // the direction of the smallest spread
  if (n.dot(side) < 0.0) n = -n;
  return {centre, n};
}

}  // namespace

MeasuredSeal measuredSeal(const Points3& measured, const Vec3& contact, const Vec3& approach,
                          const CandidateConfig& config) {
  constexpr int kRimPoints = 16;
  constexpr size_t kMiddlePoints = 6;  // fewer under the cup's middle: the camera did not see it
  const Vec3 a = approach.normalized();
  const double r = config.cup_radius_m;
  Points3 under, middle;
  for (const Vec3& p : measured) {
    const Vec3 d = p - contact;
    const double along = d.dot(a), radial = (d - along * a).norm();
    if (!(std::abs(along) <= r && radial <= 1.4 * r)) continue;  // a NaN point too
    under.push_back(p);
    if (radial <= 0.5 * r) middle.push_back(p);
  }
  MeasuredSeal out;
  out.seen = middle.size() >= kMiddlePoints;
  if (!out.seen) return out;
  // The plane the cup's middle lands on, refitted on every point under the cup near it (the
  // sensor's noise on a patch of a centimetre tilts a plane of the middle alone by degrees).
  auto [centre, n] = fitPlane(middle, a);
  Points3 near;
  for (const Vec3& p : under)
    if (std::abs((p - centre).dot(n)) <= 2.0 * config.seal_tolerance_m) near.push_back(p);
  // Too few near that plane (layers, a step under the middle): seen, and no face to seal on.
  if (near.size() < kMiddlePoints) return out;
  std::tie(centre, n) = fitPlane(near, a);
  out.normal = n;
  out.centre = centre;
  // The rim: at each of its points, the measured points within 0.4 radii of it (across the
  // plane) must exist (no hole, no edge with nothing of the target beyond it, nothing in
  // front) and lie, on average, within the tolerance of the plane.
  const Vec3 u = perpendicular(n), v = n.cross(u);
  out.deviation_m = 0.0;
  for (int k = 0; k < kRimPoints; ++k) {
    const double phi = 2.0 * M_PI * k / kRimPoints;
    const Vec3 rim = contact + r * (std::cos(phi) * u + std::sin(phi) * v);
    double sum = 0.0;
    int count = 0;
    for (const Vec3& p : under) {
      const Vec3 d = p - rim;
      if ((d - d.dot(n) * n).norm() > 0.4 * r) continue;
      sum += (p - centre).dot(n);
      ++count;
    }
    if (count == 0) {
      out.deviation_m = std::numeric_limits<double>::infinity();
      break;
    }
    const double deviation = std::abs(sum / count);
    if (std::isnan(deviation)) {  // a plane or points not finite: no seal
      out.deviation_m = deviation;
      break;
    }
    out.deviation_m = std::max(out.deviation_m, deviation);
  }
  out.seals = out.deviation_m <= config.seal_tolerance_m;
  return out;
}

bool seenThrough(const Points3& measured_table, const Vec3& contact, const Vec3& normal,
                 const Vec3& camera, double cup_radius_m) {
  constexpr int kBehindPoints = 3;  // fewer could be noise or a mixed pixel at an edge
  // Past 70 degrees from the normal the line of sight runs along the face: its own points
  // would lie on it far beyond the contact.
  const double cos_grazing = std::cos(70.0 * M_PI / 180.0);
  const double reach = (contact - camera).norm();
  const Vec3 n = normal.normalized();
  if (!(reach > 0.0) || !n.allFinite()) return false;
  const Vec3 ray = (contact - camera) / reach;
  if (-ray.dot(n) < cos_grazing) return false;
  const double near = cup_radius_m / 3.0;
  int behind = 0;
  for (const Vec3& p : measured_table) {
    const double t = (p - camera).dot(ray);
    if ((p - camera - t * ray).norm() > near) continue;
    if (std::abs(t - reach) <= near) return false;  // the surface is at the contact
    // Beyond the contact and a cup's radius inside the estimated surface: seen through it.
    if (t > reach + cup_radius_m && (contact - p).dot(n) > cup_radius_m) ++behind;
  }
  return behind >= kBehindPoints;
}

CandidateSet suctionCandidates(const std::vector<SuperquadricShape>& scene, int target,
                               const std::vector<Vec3>& camera_positions,
                               const CandidateConfig& config, const Points3& measured,
                               const std::optional<Vec3>& measured_from) {
  validate(scene, target, config);
  // A camera at or below the table plane measured no pile (a pose left at the identity).
  const bool measuring_camera =
      measured_from && measured_from->allFinite() && measured_from->z() > 0.0;
  const SuperquadricShape& sq = scene[target];
  RenderConfig render;
  render.table_half_size_m = 10.0;
  const DepthRenderer renderer(Scene::fromSuperquadrics(scene), render);
  std::mt19937_64 rng(config.seed);
  CandidateSet out;
  std::vector<SuctionCandidate> sealable;
  // The points whose pull passes through or near the centre of mass first (they seed the
  // spread), then the random ones.
  std::vector<SurfacePoint> samples = centredSamples(sq, config.cup_radius_m);
  const size_t centred = samples.size();
  for (const SurfacePoint& s : sq.sampleSurfaceObject(config.surface_samples, rng))
    samples.push_back(s);
  size_t seeds = 0;
  for (size_t k = 0; k < samples.size(); ++k) {
    const SurfacePoint& s = samples[k];
    ++out.surface_samples;
    SuctionCandidate c;
    c.contact_table = sq.T_table_object * s.position;
    c.approach_table = (sq.T_table_object.linear() * s.normal).normalized();
    if (!seenFromAny(renderer, target + 1, c.contact_table, c.approach_table, camera_positions))
      continue;
    ++out.visible;
    if ((c.contact_table + config.tool_length_m * c.approach_table).z() <= 0.0) continue;
    ++out.reachable;
    c.rim_deviation_m = rimDeviation(sq, c.contact_table, c.approach_table, config.cup_radius_m,
                                     config.rim_points, config.seal_tolerance_m);
    if (!(c.rim_deviation_m <= config.seal_tolerance_m)) continue;
    c.seal_score = 1.0 - c.rim_deviation_m / config.seal_tolerance_m;
    if (!measured.empty()) {
      const MeasuredSeal m = measuredSeal(measured, c.contact_table, c.approach_table, config);
      if (m.seen && !m.seals) continue;  // the camera saw an edge, a bend or a gap there
      // Nothing measured under the cup, and the camera looked past the estimate's surface
      // there (a cup's mouth, a bowl's inside).
      if (!m.seen && measuring_camera &&
          seenThrough(measured, c.contact_table, c.approach_table, *measured_from,
                      config.cup_radius_m)) {
        ++out.seen_through;
        continue;
      }
      if (m.seen) {
        // The measured surface's normal, and the contact on its plane.
        c.approach_table = m.normal;
        c.contact_table -= (c.contact_table - m.centre).dot(m.normal) * m.normal;
        c.seal_score = 1.0 - m.deviation_m / config.seal_tolerance_m;
        c.measured = true;
      }
    }
    sealable.push_back(c);
    if (k < centred) ++seeds;
  }
  out.sealable = static_cast<int>(sealable.size());
  for (const SuctionCandidate& c : sealable) out.measured += c.measured;
  out.candidates = spread(sealable, config.max_candidates, seeds);
  return out;
}

Transform toolPose(const SuctionCandidate& candidate) {
  const Vec3 z = -candidate.approach_table.normalized();
  const Vec3 reference =
      std::abs(z.x()) < std::cos(10.0 * M_PI / 180.0) ? Vec3::UnitX() : Vec3::UnitY();
  const Vec3 x = (reference - reference.dot(z) * z).normalized();
  Transform T = Transform::Identity();
  T.linear().col(0) = x;
  T.linear().col(1) = z.cross(x);
  T.linear().col(2) = z;
  T.translation() = candidate.contact_table;
  return T;
}

Transform pregraspPose(const Transform& tool, double distance_m) {
  if (!(std::isfinite(distance_m) && distance_m >= 0.0))
    throw std::invalid_argument("pre-grasp distance must be finite and >= 0, got " +
                                std::to_string(distance_m));
  Transform T = tool;
  T.translation() -= distance_m * tool.linear().col(2);
  return T;
}

}  // namespace simstack
