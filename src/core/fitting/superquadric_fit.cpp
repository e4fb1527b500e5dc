#include "simstack/fitting/superquadric_fit.h"

#include <ceres/ceres.h>
#include <ceres/rotation.h>

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <array>
#include <cmath>
#include <exception>
#include <limits>
#include <optional>
#include <random>
#include <stdexcept>
#include <string>
#include <tuple>
#include <unordered_map>

namespace simstack {
namespace {

// Parameter block of one shape: scale a1..a3, exponents r s t, translation, angle-axis
// (object -> table).
constexpr int kParams = 12;
using Params = std::array<double, kParams>;

// Ceres solves in an unbounded space: scale a = a_min + (a_max - a_min) sigmoid(u) and exponent
// e = e_min + (e_max - e_min) sigmoid(v), so that the bounds (positive size, convex shape, the
// ranges of the config) hold by construction and no trial step can overflow. Bounds inside
// Ceres cost a projected line search per step (three Jacobian evaluations per iteration on
// network surfaces). Box-like surfaces push
// exponents to the top of their range, where the sigmoid flattens instead of overflowing.
struct Bounds {
  double min_scale, max_scale, min_exponent, max_exponent;
};

template <typename T>
T sigmoid(const T& v) {
  return T(0.5) * (T(1.0) + tanh(T(0.5) * v));  // stable for any v
}

template <typename T>
void toShape(const T* u, const Bounds& b, T* x) {
  for (int i = 0; i < 3; ++i) {
    x[i] = T(b.min_scale) + T(b.max_scale - b.min_scale) * sigmoid(u[i]);
    x[3 + i] = T(b.min_exponent) + T(b.max_exponent - b.min_exponent) * sigmoid(u[3 + i]);
  }
  for (int i = 6; i < kParams; ++i) x[i] = u[i];
}

inline double valueOf(double v) { return v; }
template <typename S, int N>
double valueOf(const ceres::Jet<S, N>& v) {
  return v.a;
}

/// log sum_i exp(log_w_i + mu e_i), and its slope in mu (the terms' mean exponent); `shares`,
/// when given, receives each term's share of the sum, `curvature` the second derivative in mu
/// (the variance of the exponents under those shares).
template <typename T>
T logSumExp(const T* log_w, const T* e, const T& mu, T* slope, T* shares = nullptr,
            T* curvature = nullptr) {
  T terms[3];
  int k = 0;
  for (int i = 0; i < 3; ++i) {
    terms[i] = log_w[i] + mu * e[i];
    if (terms[i] > terms[k]) k = i;
  }
  const T top = terms[k];
  T sum(0.0), weighted(0.0), squared(0.0), w[3];
  for (int i = 0; i < 3; ++i) {
    w[i] = i == k ? T(1.0) : exp(terms[i] - top);  // the largest term is exactly 1
    sum += w[i];
    weighted += e[i] * w[i];
    if (curvature) squared += e[i] * e[i] * w[i];
  }
  if (slope) *slope = weighted / sum;
  if (shares)
    for (int i = 0; i < 3; ++i) shares[i] = w[i] / sum;
  if (curvature) {
    const T mean = weighted / sum;
    *curvature = squared / sum - mean * mean;
    if (*curvature < T(0.0)) *curvature = T(0.0);  // rounding
  }
  return top + log(sum);
}

/// The ray's root on plain numbers: mu = log(lambda) where h(mu) = log sum_i |q_i/a_i|^e_i
/// exp(mu e_i) = 0, by Halley's method on the convex log-sum-exp from mu = 0 (the point itself:
/// the fit's points lie near the surface) until |h| < 1e-13 (one step for equal exponents) or 8
/// steps; with h, its slope and the terms' shares at the last mu.
struct RayRoot {
  double mu, value, slope, shares[3];
};

/// `log_w` are log |q_i/a_i|^e_i, `norm` is |q|. None when the ray has no direction (q at the
/// centre): the callers then report the smallest semi-axis. Deep inside a box-like shape
/// log f is hundreds below zero; everything stays in logs, so that is no limit.
std::optional<RayRoot> rayRoot(const double* log_w, const double* e, double norm) {
  if (norm < 1e-7) return std::nullopt;
  RayRoot r;
  r.mu = 0.0;
  bool been_inside = false;
  for (int it = 0;; ++it) {
    double curvature = 0.0;
    r.value = logSumExp(log_w, e, r.mu, &r.slope, r.shares, &curvature);
    if (std::abs(r.value) < 1e-13 || it == 8) return r;
    // Halley's step (h'' is the terms' variance of e), or Newton's where Halley's would be
    // more than twice as long, and outside (h > 0) once an iterate has been inside: from
    // outside, Newton's steps on the convex h stay outside and descend onto the root, while
    // Halley's longer ones could jump back in and cycle.
    been_inside = been_inside || r.value < 0.0;
    const double denominator = 2.0 * r.slope * r.slope - r.value * curvature;
    const bool halley = denominator > r.slope * r.slope && !(been_inside && r.value > 0.0);
    r.mu -= halley ? 2.0 * r.value * r.slope / denominator : r.value / r.slope;
  }
}

/// Signed distance from the shape's surface along the ray centre -> q, for q in the shape's
/// own frame (see the header).
template <typename T>
T localRayDistance(const T* x, const T* q) {
  // Everything in logs: exponents up to 100 over- and underflow doubles otherwise.
  T lw[3];  // log |q_i / a_i|^e_i
  for (int i = 0; i < 3; ++i)
    lw[i] = T(0.5) * x[3 + i] * log(q[i] * q[i] / (x[i] * x[i]) + T(1e-18));
  double lw_v[3], e_v[3];
  for (int i = 0; i < 3; ++i) {
    lw_v[i] = valueOf(lw[i]);
    e_v[i] = valueOf(x[3 + i]);
  }
  const T norm = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + T(1e-18));
  const std::optional<RayRoot> root = rayRoot(lw_v, e_v, valueOf(norm));
  if (!root) {
    T smallest = x[0];
    if (x[1] < smallest) smallest = x[1];
    if (x[2] < smallest) smallest = x[2];
    return -smallest;
  }
  // The root on plain numbers, then one more Newton step in T. At the root that step's
  // derivatives are the implicit function's (d mu = -dh / h'), so the derivatives are exact
  // while the solver's dual numbers go through one evaluation instead of one per step.
  T slope;
  const T value = logSumExp(lw, &x[3], T(root->mu), &slope);
  const T mu = T(root->mu) - value / slope;
  return norm * (T(1.0) - exp(mu));
}

/// The same for p in the table frame.
template <typename T>
T rayDistance(const T* x, const T* p) {
  const T d[3] = {p[0] - x[6], p[1] - x[7], p[2] - x[8]};
  const T inverse[3] = {-x[9], -x[10], -x[11]};
  T q[3];
  ceres::AngleAxisRotatePoint(inverse, d, q);
  return localRayDistance(x, q);
}

/// localRayDistance on plain numbers with its derivatives: in the scales and exponents
/// (`d_shape`, x[0..5]) and in the local point (`d_q`). Eq. 5's residuals take these instead of
/// dual numbers: the same distance, with the derivatives of the same final Newton step less its
/// term in h d(1 / h'), negligible once |h| < 1e-13.
struct LocalDistance {
  double value = 0.0;
  std::array<double, 6> d_shape{};
  std::array<double, 3> d_q{};
};

LocalDistance localDistanceWithDerivatives(const double* x, const double* q) {
  LocalDistance out;
  double s[3], lw[3];
  for (int i = 0; i < 3; ++i) {
    s[i] = q[i] * q[i] / (x[i] * x[i]) + 1e-18;
    lw[i] = 0.5 * x[3 + i] * std::log(s[i]);
  }
  const double norm = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + 1e-18);
  const double* e = &x[3];
  const std::optional<RayRoot> r = rayRoot(lw, e, norm);
  if (!r) {
    const int k = static_cast<int>(std::min_element(x, x + 3) - x);
    out.value = -x[k];
    out.d_shape[k] = -1.0;
    return out;
  }
  const double root = r->mu - r->value / r->slope;
  // d root = -d value / slope, with d value = sum_i share_i (d lw_i + mu d e_i).
  const double along = norm * std::exp(root);  // |q| lambda
  out.value = norm - along;
  for (int i = 0; i < 3; ++i) {
    const double d_root_d_lw = -r->shares[i] / r->slope;
    const double d_lw_d_q = e[i] * q[i] / (x[i] * x[i] * s[i]);
    out.d_shape[i] = -along * d_root_d_lw * (-d_lw_d_q * q[i] / x[i]);
    out.d_shape[3 + i] = -along * d_root_d_lw * (lw[i] / e[i] + r->mu);  // lw_i / e_i = log s_i / 2
    out.d_q[i] = (1.0 - along / norm) * q[i] / norm - along * d_root_d_lw * d_lw_d_q;
  }
  return out;
}

/// A point on the surface of every superquadric, whatever its sizes and exponents: the signed
/// shares w (|w_1| + |w_2| + |w_3| = 1) of the implicit function's three terms, so that the
/// local point a_i sign(w_i) |w_i|^(1 / e_i) satisfies eq. 4 exactly. A sample therefore stays
/// on the surface while the solver changes the exponents; a sample frozen in the unit shape's
/// coordinates would leave it, and let a box-like shape grow corners between the samples that
/// guard its contacts.
using SurfaceSample = Vec3;

/// Table-frame position of surface sample w on shape x.
template <typename T>
void placeSample(const T* x, const SurfaceSample& w, T* p) {
  T local[3];
  for (int i = 0; i < 3; ++i) {
    const double share = std::abs(w[i]);
    local[i] =
        share > 0.0 ? x[i] * T(w[i] < 0 ? -1.0 : 1.0) * exp(T(std::log(share)) / x[3 + i]) : T(0.0);
  }
  const T aa[3] = {x[9], x[10], x[11]};
  ceres::AngleAxisRotatePoint(aa, local, p);
  for (int i = 0; i < 3; ++i) p[i] += x[6 + i];
}

/// Eq. 5's residuals of all points of one shape in one block, with an analytic Jacobian: the
/// bounds' transform, the rotation and its derivatives are computed once per evaluation, and
/// each point costs a few logarithms and exponentials on plain numbers rather than dual numbers
/// carrying 12 derivatives through every operation.
class DistortionCost : public ceres::CostFunction {
 public:
  DistortionCost(Points3 points, double weight, const Bounds& lo, double volume_exponent)
      : points_(std::move(points)), weight_(weight), lo_(lo), volume_exponent_(volume_exponent) {
    set_num_residuals(static_cast<int>(points_.size()));
    mutable_parameter_block_sizes()->push_back(kParams);
  }

  bool Evaluate(double const* const* parameters, double* r, double** jacobians) const override {
    const double* u = parameters[0];
    double x[kParams];
    toShape(u, lo_, x);
    // The rotation (column-major, table from object) with its derivatives in the angle-axis.
    using Jet3 = ceres::Jet<double, 3>;
    Jet3 aa[3], R[9];
    for (int m = 0; m < 3; ++m) aa[m] = Jet3(x[9 + m], m);
    ceres::AngleAxisToRotationMatrix(aa, R);
    const double w = weight_ * std::pow(x[0] * x[1] * x[2], 0.5 * volume_exponent_);
    double* J = jacobians ? jacobians[0] : nullptr;
    // d x / d u of the bounded parameters (the rest are the solver's own).
    double dx_du[6];
    for (int i = 0; i < 6; ++i) {
      const double range =
          i < 3 ? lo_.max_scale - lo_.min_scale : lo_.max_exponent - lo_.min_exponent;
      const double t = std::tanh(0.5 * u[i]);
      dx_du[i] = 0.25 * range * (1.0 - t * t);
    }
    for (size_t k = 0; k < points_.size(); ++k) {
      const double d[3] = {points_[k].x() - x[6], points_[k].y() - x[7], points_[k].z() - x[8]};
      double q[3];
      for (int i = 0; i < 3; ++i)
        q[i] = R[3 * i].a * d[0] + R[3 * i + 1].a * d[1] + R[3 * i + 2].a * d[2];
      const LocalDistance ld = localDistanceWithDerivatives(x, q);
      r[k] = w * ld.value;
      if (!J) continue;
      double* row = J + k * kParams;
      for (int i = 0; i < 3; ++i) {
        const double d_volume = ld.value * w * 0.5 * volume_exponent_ / x[i];
        row[i] = (w * ld.d_shape[i] + d_volume) * dx_du[i];
        row[3 + i] = w * ld.d_shape[3 + i] * dx_du[3 + i];
      }
      for (int j = 0; j < 3; ++j) {  // translation: d q_i / d t_j = -R(j, i)
        double sum = 0.0;
        for (int i = 0; i < 3; ++i) sum -= ld.d_q[i] * R[3 * i + j].a;
        row[6 + j] = w * sum;
      }
      for (int m = 0; m < 3; ++m) {  // angle-axis: d q_i / d aa_m = sum_j d R(j, i) / d aa_m d_j
        double sum = 0.0;
        for (int i = 0; i < 3; ++i)
          sum += ld.d_q[i] *
                 (R[3 * i].v[m] * d[0] + R[3 * i + 1].v[m] * d[1] + R[3 * i + 2].v[m] * d[2]);
        row[9 + m] = w * sum;
      }
    }
    return true;
  }

 private:
  Points3 points_;
  double weight_;  // sqrt(lambda / N)
  Bounds lo_;
  double volume_exponent_;  // of a1 a2 a3 in the squared residuals' weight (eq. 5: 0.5)
};

struct CollisionResidual {  // sample q of shape j penetrating shape i
  Vec3 q;
  double weight;
  Bounds lo;
  template <typename T>
  bool operator()(const T* ui, const T* uj, T* r) const {
    T xi[kParams], xj[kParams];
    toShape(ui, lo, xi);
    toShape(uj, lo, xj);
    T p[3];
    placeSample(xj, q, p);
    const T d = rayDistance(xi, p);
    r[0] = d < T(0.0) ? T(weight) * d : T(0.0);
    return true;
  }
  static ceres::CostFunction* Create(const Vec3& q, double weight, const Bounds& lo) {
    return new ceres::AutoDiffCostFunction<CollisionResidual, 1, kParams, kParams>(
        new CollisionResidual{q, weight, lo});
  }
};

struct FloorResidual {
  Vec3 q;
  double weight;
  Bounds lo;
  template <typename T>
  bool operator()(const T* u, T* r) const {
    T x[kParams];
    toShape(u, lo, x);
    T p[3];
    placeSample(x, q, p);
    r[0] = p[2] < T(0.0) ? T(weight) * p[2] : T(0.0);
    return true;
  }
  static ceres::CostFunction* Create(const Vec3& q, double weight, const Bounds& lo) {
    return new ceres::AutoDiffCostFunction<FloorResidual, 1, kParams>(
        new FloorResidual{q, weight, lo});
  }
};

Params toParams(const SuperquadricShape& sq) {
  Params x;
  for (int i = 0; i < 3; ++i) {
    x[i] = sq.scale_m[i];
    x[3 + i] = sq.exponents[i];
    x[6 + i] = sq.T_table_object.translation()[i];
  }
  const Eigen::AngleAxisd aa(sq.T_table_object.linear());
  const Vec3 v = aa.angle() * aa.axis();
  for (int i = 0; i < 3; ++i) x[9 + i] = v[i];
  return x;
}

SuperquadricShape fromParams(const Params& x) {
  SuperquadricShape sq;
  sq.scale_m = Vec3(x[0], x[1], x[2]);
  sq.exponents = Vec3(x[3], x[4], x[5]);
  const Vec3 v(x[9], x[10], x[11]);
  sq.T_table_object = Transform::Identity();
  if (v.norm() > 1e-12)
    sq.T_table_object.linear() = Eigen::AngleAxisd(v.norm(), v / v.norm()).toRotationMatrix();
  sq.T_table_object.translation() = Vec3(x[6], x[7], x[8]);
  return sq;
}

void clampToBounds(Params* x, const FitConfig& c) {
  for (int i = 0; i < 3; ++i) {
    (*x)[i] = std::clamp((*x)[i], c.min_scale_m, c.max_scale_m);
    (*x)[3 + i] = std::clamp((*x)[3 + i], c.min_exponent, c.max_exponent);
  }
}

Bounds solverBounds(const FitConfig& c) {
  return {c.min_scale_m, c.max_scale_m, c.min_exponent, c.max_exponent};
}

// Shape parameters (clamped to the bounds, kept a hair inside them so that the inverse maps
// exist) to solver variables, and back.
Params toSolver(Params x, const FitConfig& c) {
  clampToBounds(&x, c);
  auto logit = [](double value, double lo, double hi) {
    const double share = std::clamp((value - lo) / (hi - lo), 1e-4, 1.0 - 1e-4);
    return std::log(share / (1.0 - share));
  };
  for (int i = 0; i < 3; ++i) {
    x[i] = logit(x[i], c.min_scale_m, c.max_scale_m);
    x[3 + i] = logit(x[3 + i], c.min_exponent, c.max_exponent);
  }
  return x;
}

Params fromSolver(const Params& u, const FitConfig& c) {
  Params x;
  toShape(u.data(), solverBounds(c), x.data());
  clampToBounds(&x, c);
  return x;
}

// Eq. 5 over all `points`, weighted by lambda / N (and (a1 a2 a3)^volume_exponent).
void addDistortion(ceres::Problem* problem, double* x, const Points3& points, double lambda,
                   const Bounds& lo, double volume_exponent = 0.5) {
  const double weight = std::sqrt(lambda / points.size());
  problem->AddResidualBlock(new DistortionCost(points, weight, lo, volume_exponent), nullptr, x);
}

// One point per cell of a cubic grid whose cell is chosen so that about `target` cells are
// occupied (the point nearest the cell's centroid): an even cover of the surface, in which
// dense patches do not outvote sparse ones. Centroids themselves would sit inside curved
// surfaces and round off edges.
Points3 surfaceCover(const Points3& points, int target) {
  if (static_cast<int>(points.size()) <= target) return points;
  Vec3 lo = points[0], hi = points[0];
  for (const Vec3& p : points) {
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  }
  const Vec3 e = (hi - lo).cwiseMax(1e-6);
  // A surface spanning the box has about the box's surface area, so cells of side h hold it in
  // about area / h^2 cells; up to two corrections from the count found bring it near the target.
  double cell = std::sqrt(2.0 * (e.x() * e.y() + e.y() * e.z() + e.z() * e.x()) / target);
  std::vector<uint64_t> keys(points.size());
  std::unordered_map<uint64_t, std::pair<Vec3, int>> cells;
  for (int attempt = 0; attempt < 3; ++attempt) {
    cells.clear();
    for (size_t k = 0; k < points.size(); ++k) {
      const Eigen::Array3d c = ((points[k] - lo) / cell).array().floor();
      keys[k] = (static_cast<uint64_t>(c.x()) << 42) | (static_cast<uint64_t>(c.y()) << 21) |
                static_cast<uint64_t>(c.z());
      auto& [sum, count] = cells.try_emplace(keys[k], Vec3::Zero(), 0).first->second;
      sum += points[k];
      ++count;
    }
    const double ratio = static_cast<double>(cells.size()) / target;
    if (ratio > 0.8 && ratio < 1.25) break;
    cell *= std::sqrt(ratio);
  }
  std::unordered_map<uint64_t, std::pair<size_t, double>> nearest;
  for (size_t k = 0; k < points.size(); ++k) {
    const auto& [sum, count] = cells.at(keys[k]);
    const double d = (points[k] - sum / count).squaredNorm();
    auto [it, fresh] = nearest.try_emplace(keys[k], k, d);
    if (!fresh && d < it->second.second) it->second = {k, d};
  }
  std::vector<size_t> chosen;
  for (const auto& [key, pick] : nearest) chosen.push_back(pick.first);
  std::sort(chosen.begin(), chosen.end());  // input order: reproducible whatever the hashing
  Points3 out;
  for (size_t k : chosen) out.push_back(points[k]);
  return out;
}

ceres::Solver::Options solverOptions(const FitConfig& c, int max_iterations) {
  ceres::Solver::Options o;
  o.trust_region_strategy_type = ceres::DOGLEG;
  o.linear_solver_type =
      ceres::DENSE_NORMAL_CHOLESKY;  // 12 parameters per shape: tiny normal equations
  o.max_num_iterations = max_iterations;
  // Ceres' default first trust region (1e4) is far beyond the scale of these parameters
  // (centimetres, size and exponent logits): every early step overshot, the dogleg halves the
  // radius per rejected step, and a 15-iteration solve spent all of them shrinking it and
  // returned its starting point.
  o.initial_trust_region_radius = 1.0;
  o.num_threads = std::max(1, c.threads);
  o.logging_type = ceres::SILENT;
  return o;
}

/// Near-uniform surface samples of the shape with the given exponents, as SurfaceSamples.
std::vector<SurfaceSample> unitSamples(const Vec3& exponents, int count, uint64_t seed) {
  SuperquadricShape unit;
  unit.scale_m = Vec3::Ones();
  unit.exponents = exponents;
  std::mt19937_64 rng(seed);
  std::vector<SurfaceSample> out;
  // Area-weighted on a coarse mesh (12 cells a face), then onto the exact surface: near enough
  // to uniform for contact samples, and a tenth of the finer mesh's cost (this runs for every
  // shape in every joint round).
  for (const SurfacePoint& s : unit.meshObject(12).sampleSurface(count, rng)) {
    const Vec3 p = unit.surfacePointAlong(s.position);
    SurfaceSample w;
    for (int i = 0; i < 3; ++i) w[i] = std::copysign(std::pow(std::abs(p[i]), exponents[i]), p[i]);
    const double sum = w.cwiseAbs().sum();
    if (sum > 0.0) out.push_back(w / sum);
  }
  return out;
}

void checkPoints(const Points3& points) {
  if (points.size() < 4)
    throw std::invalid_argument("superquadric fitting needs at least 4 points, got " +
                                std::to_string(points.size()));
  for (const Vec3& p : points)
    if (!p.allFinite()) throw std::invalid_argument("superquadric fitting: non-finite point");
}

}  // namespace

void FitConfig::validate() const {
  auto require = [](bool ok, const std::string& what) {
    if (!ok) throw std::invalid_argument("fitting config: " + what);
  };
  require(min_scale_m > 0.0 && max_scale_m > min_scale_m, "need 0 < min_scale_m < max_scale_m");
  require(min_exponent >= 1.0 && max_exponent > min_exponent && max_exponent <= 200.0,
          "need 1 <= min_exponent < max_exponent <= 200 (exponents below 1 are not convex; "
          "above 200 |x / a|^e over- or underflows, and the grasp ranking refuses them)");
  require(max_scale_m <= 10.0, "max_scale_m must be at most 10 m");
  require(initial_exponent >= min_exponent && initial_exponent <= max_exponent,
          "initial_exponent must lie in [min_exponent, max_exponent]");
  require(lambda_dist >= 0.0 && lambda_coll >= 0.0 && lambda_floor >= 0.0,
          "lambda_dist, lambda_coll and lambda_floor must be >= 0");
  require(max_points >= 4 && coarse_points >= 4 && joint_points >= 4 && shape_samples >= 1,
          "need max_points, coarse_points and joint_points >= 4, and shape_samples >= 1");
  require(surrounded_share >= 0.0, "surrounded_share must be >= 0 (above 1: never)");
  require(one_sided_volume_exponent >= 0.0 && one_sided_volume_exponent <= 0.5,
          "one_sided_volume_exponent must lie in [0, 0.5] (0.5: eq. 5's weight throughout)");
  require(one_sided_growth_limit >= 1.0, "one_sided_growth_limit must be >= 1");
  require(contact_margin_m >= 0.0, "contact_margin_m must be >= 0");
  require(joint_rounds >= 1 && start_iterations >= 1 && max_iterations >= 1 &&
              joint_max_iterations >= 1 && threads >= 1,
          "joint_rounds, start_iterations, max_iterations, joint_max_iterations and threads "
          "must be >= 1");
}

double surfaceDistance(const SuperquadricShape& sq, const Vec3& p_table) {
  const Params x = toParams(sq);
  const double p[3] = {p_table.x(), p_table.y(), p_table.z()};
  return rayDistance(x.data(), p);
}

double meanDistortion(const SuperquadricShape& sq, const Points3& points_table) {
  if (points_table.empty()) return 0.0;
  double sum = 0;
  for (const Vec3& p : points_table) {
    const double d = surfaceDistance(sq, p);
    sum += d * d;
  }
  return std::sqrt(sq.scale_m.prod()) * sum / points_table.size();
}

namespace {

/// The points' mean and the eigen-decomposition of their scatter matrix (eigenvalues
/// ascending: n times the variances along the principal directions).
struct PrincipalAxes {
  Vec3 mean;
  Eigen::SelfAdjointEigenSolver<Mat3> eigen;
};

PrincipalAxes principalAxes(const Points3& points) {
  PrincipalAxes out;
  out.mean = Vec3::Zero();
  for (const Vec3& p : points) out.mean += p;
  out.mean /= points.size();
  Mat3 scatter = Mat3::Zero();
  for (const Vec3& p : points) scatter += (p - out.mean) * (p - out.mean).transpose();
  out.eigen.compute(scatter);
  return out;
}

/// Standard deviations of `points` along its principal directions (ascending).
Vec3 principalSpread(const PrincipalAxes& axes, const Points3& points) {
  return (axes.eigen.eigenvalues() / points.size()).cwiseMax(0.0).cwiseSqrt();
}

}  // namespace

SuperquadricShape initialGuess(const Points3& points, double initial_exponent) {
  checkPoints(points);
  const PrincipalAxes principal = principalAxes(points);
  const Vec3& mean = principal.mean;
  Mat3 axes = principal.eigen.eigenvectors();
  if (axes.determinant() < 0) axes.col(0) = -axes.col(0);
  Vec3 lo = Vec3::Constant(1e9), hi = Vec3::Constant(-1e9);
  for (const Vec3& p : points) {
    const Vec3 l = axes.transpose() * (p - mean);
    lo = lo.cwiseMin(l);
    hi = hi.cwiseMax(l);
  }
  SuperquadricShape sq;
  sq.scale_m = (0.5 * (hi - lo)).cwiseMax(1e-3);
  sq.exponents = Vec3::Constant(initial_exponent);
  sq.T_table_object = Transform::Identity();
  sq.T_table_object.linear() = axes;
  sq.T_table_object.translation() = mean + axes * (0.5 * (hi + lo));
  return sq;
}

namespace {

// The bounding box of the points, pointed and flat-faced versions of it, and, for a view of
// one side, two deeper boxes.
std::vector<SuperquadricShape> startingShapes(const SuperquadricShape& box) {
  std::vector<SuperquadricShape> starts{box};
  // Pointed (octahedron-like) and flat-faced versions of the box: the exponents move slowly
  // between them through the solver's bounded parametrisation.
  for (const double e : {1.3, 8.0}) {
    SuperquadricShape other = box;
    other.exponents = Vec3::Constant(e);
    if (e != box.exponents.x()) starts.push_back(other);
  }
  // A view of one side covers about half of the object, and the points' thinnest principal
  // axis is then near the line of sight: the whole object may reach as far again behind the
  // points, on either side of them (the side the camera was on is not known here).
  int thin = 0;
  box.scale_m.minCoeff(&thin);
  for (const double side : {-1.0, 1.0}) {
    SuperquadricShape deeper = box;
    deeper.scale_m[thin] *= 2.0;
    deeper.T_table_object.translation() +=
        side * box.scale_m[thin] * box.T_table_object.linear().col(thin);
    starts.push_back(deeper);
  }
  return starts;
}

// The alternatives of a fitted shape that a local solve cannot reach from it. About each axis
// k, the cross-section |x|^p + |y|^p <= 1 turned by 45 degrees is close to the one of the
// conjugate exponent p / (p - 1), scaled by 2^(1/2 - 1/p): exactly so for the diamond (p = 1)
// and the square (p = infinity), and the circle (p = 2) maps to itself. The solver passes
// between the two only through worse fits: a box seen across an edge is fitted as a diamond
// prism, an octahedron as a box with rounded edges.
std::vector<SuperquadricShape> switchedShapes(const SuperquadricShape& sq) {
  std::vector<SuperquadricShape> out;
  for (int k = 0; k < 3; ++k) {
    const int i = (k + 1) % 3, j = (k + 2) % 3;
    const double p = std::sqrt(sq.exponents[i] * sq.exponents[j]);
    if (p > 1.6 && p < 2.5) continue;  // round: turning it changes little
    const double q = p > 20.0 ? 1.05 : std::max(1.05, p / (p - 1.0));
    const double scale = 0.5 * (sq.scale_m[i] + sq.scale_m[j]) * std::pow(2.0, 0.5 - 1.0 / p);
    SuperquadricShape turned = sq;
    turned.T_table_object.linear() =
        sq.T_table_object.linear() *
        Eigen::AngleAxisd(0.25 * 3.14159265358979323846, Vec3::Unit(k)).toRotationMatrix();
    turned.scale_m[i] = turned.scale_m[j] = scale;
    turned.exponents[i] = turned.exponents[j] = std::min(q, 50.0);
    out.push_back(turned);
  }
  return out;
}

// The share of 54 cells of directions about the shape's centre (the faces of a cube, 3 x 3
// cells each, in the shape's frame scaled by its sizes) that hold at least one point: near 1
// for a surface seen from all sides, about half for a view of one side.
double surroundedShare(const SuperquadricShape& sq, const Points3& points) {
  std::array<bool, 54> hit{};
  const Mat3 R = sq.T_table_object.linear();
  const Vec3 t = sq.T_table_object.translation();
  for (const Vec3& p : points) {
    const Vec3 q = (R.transpose() * (p - t)).cwiseQuotient(sq.scale_m);
    int axis = 0;
    const double m = q.cwiseAbs().maxCoeff(&axis);
    if (!(m >= 1e-12)) continue;  // at the centre, or NaN from a diverged solve
    const auto cell = [&](int i) {
      return std::clamp(static_cast<int>((q[(axis + i) % 3] / m + 1.0) * 1.5), 0, 2);
    };
    hit[9 * (2 * axis + (q[axis] > 0)) + 3 * cell(1) + cell(2)] = true;
  }
  return std::count(hit.begin(), hit.end(), true) / 54.0;
}

struct Solution {
  Params u;  // solver variables
  double cost = std::numeric_limits<double>::infinity();
};

Solution solveFrom(const Params& start, const Points3& points, const FitConfig& c, int iterations,
                   double volume_exponent = 0.5) {
  Solution s{start};
  ceres::Problem problem;
  addDistortion(&problem, s.u.data(), points, 1.0, solverBounds(c), volume_exponent);
  ceres::Solver::Summary summary;
  ceres::Solve(solverOptions(c, iterations), &problem, &summary);
  s.cost = summary.final_cost;
  return s;
}

}  // namespace

SuperquadricShape fitSuperquadric(const Points3& points, const FitConfig& c,
                                  const std::optional<SuperquadricShape>& start) {
  c.validate();
  checkPoints(points);
  const Points3 coarse = surfaceCover(points, c.coarse_points);
  if (coarse.size() < 4)
    throw std::invalid_argument("superquadric fitting: the points lie at fewer than 4 places");
  // Each start gets a short solve on the coarse cover; the best is solved to convergence.
  const SuperquadricShape box = initialGuess(coarse, c.initial_exponent);
  std::vector<SuperquadricShape> starts = startingShapes(box);
  if (start) starts.push_back(*start);
  // A solve that shrinks the shape far below its points' extent is in the degenerate basin
  // (see the header): it never wins, whatever its cost.
  const double least_reach = 0.25 * box.scale_m.maxCoeff();
  const auto admissible = [&](const Solution& s) {
    return fromParams(fromSolver(s.u, c)).scale_m.maxCoeff() >= least_reach;
  };
  Solution best;
  for (const SuperquadricShape& s0 : starts) {
    Solution s = solveFrom(toSolver(toParams(s0), c), coarse, c, c.start_iterations);
    if (admissible(s) && s.cost < best.cost) best = s;
  }
  if (!std::isfinite(best.cost)) best.u = toSolver(toParams(box), c);
  best = solveFrom(best.u, coarse, c, c.max_iterations);
  // Then the switched alternatives of the result, each solved in turn; a better one replaces
  // it (and is switched again, a few times at most).
  for (int round = 0; round < 3; ++round) {
    bool improved = false;
    for (const SuperquadricShape& alt : switchedShapes(fromParams(fromSolver(best.u, c)))) {
      Solution s = solveFrom(toSolver(toParams(alt), c), coarse, c, c.start_iterations);
      if (!admissible(s) || s.cost >= best.cost) continue;
      s = solveFrom(s.u, coarse, c, c.max_iterations);
      if (admissible(s) && s.cost < best.cost) {
        best = s;
        improved = true;
      }
    }
    if (!improved) break;
  }
  // Last, the chosen basin on the finer cover; then, when the points surround the shape, a few
  // steps on every point from there (start_iterations: on measured surfaces the solve has
  // converged by then, on a network's surface it would creep on for 20-30 iterations); when
  // they do not, a solve with the weaker volume weight, unless it lets the shape grow.
  const Points3 fine = surfaceCover(points, c.max_points);
  if (fine.size() > coarse.size()) best = solveFrom(best.u, fine, c, c.max_iterations);
  const auto volume = [&](const Solution& s) {
    return fromParams(fromSolver(s.u, c)).scale_m.prod();
  };
  if (surroundedShare(fromParams(fromSolver(best.u, c)), points) >= c.surrounded_share) {
    if (points.size() > fine.size()) best = solveFrom(best.u, points, c, c.start_iterations);
  } else if (c.one_sided_volume_exponent < 0.5) {
    const Solution s = solveFrom(best.u, fine, c, c.max_iterations, c.one_sided_volume_exponent);
    if (volume(s) <= c.one_sided_growth_limit * volume(best)) best = s;
  }
  return canonicalSuperquadric(fromParams(fromSolver(best.u, c)));
}

std::vector<SuperquadricShape> refineJointly(const std::vector<Points3>& points,
                                             const std::vector<SuperquadricShape>& shapes,
                                             const FitConfig& c) {
  c.validate();
  if (points.size() != shapes.size())
    throw std::invalid_argument("refineJointly: one point set per shape is required");
  const size_t n = shapes.size();
  const Bounds lo = solverBounds(c);
  std::vector<Params> u(n), x(n);
  std::vector<Points3> subset(n);
  for (size_t i = 0; i < n; ++i) {
    // Every n-th point: the joint solve keeps the points' own spread (why not a surface cover:
    // docs/experiments.md, "Fitting").
    const size_t stride =
        std::max<size_t>(1, (points[i].size() + c.joint_points - 1) / c.joint_points);
    for (size_t k = 0; k < points[i].size(); k += stride) subset[i].push_back(points[i][k]);
    u[i] = toSolver(toParams(shapes[i]), c);
    x[i] = fromSolver(u[i], c);
  }
  // Active-set rounds: the collision and floor terms are hinges, zero for every sample that is
  // clear of the other shape (or above the floor). Each round keeps only the samples within
  // contact_margin_m of penetrating, at the shapes of the round's start, so that a dense sample
  // set costs the solver a few dozen residuals; samples that come close during a round join
  // in the next one. Contacts that form during the last round get one more round.
  for (int round = 0, rounds = c.joint_rounds; round < rounds; ++round) {
    ceres::Problem problem;
    std::vector<std::pair<size_t, const SurfaceSample*>> left_out_floor;
    std::vector<std::tuple<size_t, size_t, const SurfaceSample*>> left_out_pairs;
    std::vector<std::vector<SurfaceSample>> samples(n);
    std::vector<SuperquadricShape> current(n);
    for (size_t i = 0; i < n; ++i) {
      problem.AddParameterBlock(u[i].data(), kParams);
      if (!subset[i].empty()) addDistortion(&problem, u[i].data(), subset[i], c.lambda_dist, lo);
      samples[i] = unitSamples(Vec3(x[i][3], x[i][4], x[i][5]), c.shape_samples, 977 * round + i);
      current[i] = fromParams(x[i]);
    }
    for (size_t i = 0; i < n; ++i) {
      const double floor_w = std::sqrt(c.lambda_floor);  // eq. 9 sums, it has no 1/N
      for (const Vec3& q : samples[i]) {
        double p[3];
        placeSample(x[i].data(), q, p);
        if (p[2] > c.contact_margin_m) {
          left_out_floor.emplace_back(i, &q);
          continue;
        }
        problem.AddResidualBlock(FloorResidual::Create(q, floor_w, lo), nullptr, u[i].data());
      }
      for (size_t j = 0; j < n; ++j) {
        if (i == j) continue;
        // Only pairs whose bounding spheres meet can collide.
        const double reach_i = std::max({x[i][0], x[i][1], x[i][2]}) * std::sqrt(3.0);
        const double reach_j = std::max({x[j][0], x[j][1], x[j][2]}) * std::sqrt(3.0);
        const Vec3 ti(x[i][6], x[i][7], x[i][8]), tj(x[j][6], x[j][7], x[j][8]);
        if ((ti - tj).norm() > reach_i + reach_j + c.contact_margin_m) continue;
        const double w = std::sqrt(c.lambda_coll / samples[j].size());  // eq. 8's 1/N_j
        for (const Vec3& q : samples[j]) {
          double p[3];
          placeSample(x[j].data(), q, p);
          if (surfaceDistance(current[i], Vec3(p[0], p[1], p[2])) > c.contact_margin_m) {
            left_out_pairs.emplace_back(i, j, &q);
            continue;
          }
          problem.AddResidualBlock(CollisionResidual::Create(q, w, lo), nullptr, u[i].data(),
                                   u[j].data());
        }
      }
    }
    ceres::Solver::Summary summary;
    ceres::Solve(solverOptions(c, c.joint_max_iterations), &problem, &summary);
    for (size_t i = 0; i < n; ++i) x[i] = fromSolver(u[i], c);
    if (round + 1 == rounds && rounds == c.joint_rounds) {
      bool new_contact = false;
      for (const auto& [i, q] : left_out_floor) {
        double p[3];
        placeSample(x[i].data(), *q, p);
        new_contact = new_contact || p[2] < 0.0;
      }
      for (size_t i = 0; i < n; ++i) current[i] = fromParams(x[i]);
      for (size_t k = 0; k < left_out_pairs.size() && !new_contact; ++k) {
        const auto& [i, j, q] = left_out_pairs[k];
        double p[3];
        placeSample(x[j].data(), *q, p);
        new_contact = surfaceDistance(current[i], Vec3(p[0], p[1], p[2])) < 0.0;
      }
      if (new_contact) ++rounds;
    }
  }
  std::vector<SuperquadricShape> out;
  for (const Params& p : x) out.push_back(fromParams(p));
  return out;
}

namespace {

/// The extent of the middle 90 % of `points` along the unit `axis`: a few stray points (a
/// neighbour's edge) do not count.
double middleSpan(const Points3& points, const Vec3& axis) {
  if (points.empty()) return 0.0;
  std::vector<double> along(points.size());
  for (size_t i = 0; i < points.size(); ++i) along[i] = axis.dot(points[i]);
  const size_t cut = along.size() / 20;
  std::nth_element(along.begin(), along.begin() + cut, along.end());
  const double lo = along[cut];
  std::nth_element(along.begin(), along.end() - 1 - cut, along.end());
  return along[along.size() - 1 - cut] - lo;
}

/// The least factor `shape` may be scaled by for `points`: 0.3 of their extent, and no axis
/// along which they extend over kCollapseSpanM pressed to the fitter's bound (flattenedFit).
double leastShrink(const SuperquadricShape& shape, const Points3& points, double min_scale_m) {
  const double box = initialGuess(points).scale_m.maxCoeff();
  double least = 0.3 * box / shape.scale_m.maxCoeff();
  for (int k = 0; k < 3; ++k)
    if (middleSpan(points, shape.T_table_object.linear().col(k)) > kCollapseSpanM)
      least = std::max(least, 1.6 * min_scale_m / shape.scale_m[k]);
  return std::min(1.0, least);
}

/// `shape` scaled about its centre by the largest factor in [least, 1] (bisection) that leaves
/// it clear of every shape of `shapes` but the `self`-th (under 0.3 mm rms penetration either
/// way); `least` when none does.
SuperquadricShape shrunkUntilClear(const SuperquadricShape& shape,
                                   const std::vector<SuperquadricShape>& shapes, size_t self,
                                   double least) {
  const auto scaled = [&](double f) {
    SuperquadricShape s = shape;
    s.scale_m *= f;
    return s;
  };
  const auto clear = [&](const SuperquadricShape& s) {
    for (size_t j = 0; j < shapes.size(); ++j)
      if (j != self && collisionCost(shapes[j], s, 200) + collisionCost(s, shapes[j], 200) > 1e-7)
        return false;
    return true;
  };
  if (clear(shape)) return shape;
  if (!clear(scaled(least))) return scaled(least);
  double lo = least, hi = 1.0;  // lo is clear, hi is not
  for (int i = 0; i < 8; ++i) {
    const double mid = 0.5 * (lo + hi);
    (clear(scaled(mid)) ? lo : hi) = mid;
  }
  return scaled(lo);
}

}  // namespace

std::vector<std::optional<SuperquadricShape>> fitEachInstance(const std::vector<Points3>& points,
                                                              const FitConfig& c, int min_points) {
  c.validate();
  const int n = static_cast<int>(points.size());
  std::vector<std::optional<SuperquadricShape>> fits(n);
  FitConfig single = c;
  single.threads = 1;
  std::exception_ptr error;  // an exception must not leave the parallel loop: rethrown after it
#pragma omp parallel for schedule(dynamic) num_threads(std::max(1, c.threads))
  for (int i = 0; i < n; ++i) {
    if (static_cast<int>(points[i].size()) < std::max(4, min_points)) continue;
    try {
      fits[i] = fitSuperquadric(points[i], single);
      // The points' oriented box rather than a shape that lost them.
      if (collapsedFit(*fits[i], points[i]) || flattenedFit(*fits[i], points[i], c.min_scale_m) ||
          grownFit(*fits[i], points[i]))
        fits[i] = initialGuess(points[i], c.initial_exponent);
    } catch (const std::invalid_argument&) {
      // Points that cannot be fitted (all at a few places, or not finite): no superquadric, as
      // for too few points; the config was checked above.
    } catch (...) {
#pragma omp critical(simstack_fit_instances_error)
      if (!error) error = std::current_exception();
    }
  }
  if (error) std::rethrow_exception(error);
  return fits;
}

void refineInstances(const std::vector<Points3>& points, const FitConfig& c,
                     std::vector<std::optional<SuperquadricShape>>* fits_io) {
  c.validate();
  if (fits_io->size() != points.size())
    throw std::invalid_argument("refineInstances: " + std::to_string(fits_io->size()) +
                                " shapes for " + std::to_string(points.size()) + " point sets");
  std::vector<std::optional<SuperquadricShape>>& fits = *fits_io;
  const int n = static_cast<int>(points.size());
  std::vector<Points3> pts;
  std::vector<SuperquadricShape> shapes;
  std::vector<int> index;
  for (int i = 0; i < n; ++i) {
    if (!fits[i]) continue;
    pts.push_back(points[i]);
    shapes.push_back(*fits[i]);
    index.push_back(i);
  }
  if (shapes.empty()) return;
  std::vector<SuperquadricShape> refined = refineJointly(pts, shapes, c);
  for (size_t k = 0; k < index.size(); ++k) {
    // Points on exactly one plane or line leave eq. 5 no say in the shape's size: the joint
    // solve's volume pull shrinks it below them, so it keeps its per-instance fit.
    if (!collapsedFit(refined[k], pts[k]) && !flattenedFit(refined[k], pts[k], c.min_scale_m) &&
        !exactlyFlat(pts[k]) && refined[k].volume() >= kLeastJointVolumeShare * shapes[k].volume())
      continue;
    // The per-instance fit, made smaller until it is clear of the others, as far as its points
    // allow: the joint solve's own way out of a collision, without losing the object.
    refined[k] =
        shrunkUntilClear(shapes[k], refined, k, leastShrink(shapes[k], pts[k], c.min_scale_m));
  }
  for (size_t k = 0; k < index.size(); ++k) fits[index[k]] = refined[k];
}

std::vector<std::optional<SuperquadricShape>> fitInstances(const std::vector<Points3>& points,
                                                           const FitConfig& c, bool joint,
                                                           int min_points) {
  std::vector<std::optional<SuperquadricShape>> fits = fitEachInstance(points, c, min_points);
  if (joint) refineInstances(points, c, &fits);
  return fits;
}

bool fitAtBound(const SuperquadricShape& shape, const Points3& visible_table,
                const FitConfig& config) {
  if (visible_table.size() < 4) return false;
  return (shape.scale_m.maxCoeff() <= 1.5 * config.min_scale_m &&
          2 * initialGuess(visible_table).scale_m.maxCoeff() > kCollapseSpanM) ||
         flattenedFit(shape, visible_table, config.min_scale_m);
}

bool flattenedFit(const SuperquadricShape& shape, const Points3& points_table, double min_scale_m) {
  if (points_table.size() < 4) return false;
  for (int k = 0; k < 3; ++k)
    if (shape.scale_m[k] <= 1.5 * min_scale_m &&
        middleSpan(points_table, shape.T_table_object.linear().col(k)) > kCollapseSpanM)
      return true;
  return false;
}

bool exactlyFlat(const Points3& points_table) {
  if (points_table.size() < 4) return false;
  return principalSpread(principalAxes(points_table), points_table)[0] < kExactlyFlatM;
}

bool grownFit(const SuperquadricShape& shape, const Points3& points_table) {
  if (points_table.size() < 4) return false;
  const PrincipalAxes principal = principalAxes(points_table);
  const Vec3 spread = principalSpread(principal, points_table);
  if (spread[0] >= kExactlyFlatM) return false;  // not exactlyFlat
  const Eigen::SelfAdjointEigenSolver<Mat3>& eigen = principal.eigen;
  const Mat3 axes = shape.T_table_object.linear();
  for (int j = 0; j < 3; ++j) {
    if (spread[j] < kExactlyFlatM) continue;  // across the plane: the hidden depth is free
    const Vec3 u = eigen.eigenvectors().col(j);
    double lo = 1e9, hi = -1e9;
    for (const Vec3& p : points_table) {
      lo = std::min(lo, u.dot(p));
      hi = std::max(hi, u.dot(p));
    }
    // The shape's box bounds its extent along u from above.
    const double reach = (axes.transpose() * u).cwiseAbs().dot(shape.scale_m);
    if (reach > 1.5 * 0.5 * (hi - lo) + 0.005) return true;
  }
  return false;
}

bool collapsedFit(const SuperquadricShape& shape, const Points3& points_table) {
  if (points_table.size() < 4) return false;
  const SuperquadricShape box = initialGuess(points_table);
  return 2 * box.scale_m.maxCoeff() > kCollapseSpanM &&
         shape.scale_m.maxCoeff() < 0.25 * box.scale_m.maxCoeff();
}

void distortionResiduals(const Points3& points, const FitConfig& c, double volume_exponent,
                         const std::array<double, 12>& u, std::vector<double>* residuals,
                         std::vector<double>* jacobian) {
  const DistortionCost cost(points, std::sqrt(1.0 / points.size()), solverBounds(c),
                            volume_exponent);
  residuals->assign(points.size(), 0.0);
  jacobian->assign(points.size() * kParams, 0.0);
  const double* parameters[] = {u.data()};
  double* jacobians[] = {jacobian->data()};
  cost.Evaluate(parameters, residuals->data(), jacobians);
}

double collisionCost(const SuperquadricShape& a, const SuperquadricShape& b, int samples) {
  const Params xb = toParams(b);
  double sum = 0;
  const std::vector<SurfaceSample> q = unitSamples(b.exponents, samples, 12345);
  for (const Vec3& s : q) {
    double p[3];
    placeSample(xb.data(), s, p);
    const double d = surfaceDistance(a, Vec3(p[0], p[1], p[2]));
    if (d < 0) sum += d * d;
  }
  return q.empty() ? 0.0 : sum / q.size();
}

}  // namespace simstack
