#pragma once
/// @file superquadric_fit.h
/// One superquadric per instance (paper section 3.2.2, eqs. 5-9), solved with Ceres (dogleg).
/// The bounds (sizes, exponents in [min, max] so that shapes stay convex) are built into the
/// solver's parametrisation rather than given to Ceres as bounds.
///
/// Distance: the paper's d = |OP| (f - 1) / f saturates for box-like shapes (f grows like
/// distance^exponent), so a point 10 % outside a box of exponent 20 reads as 85 % of |OP|.
/// `surfaceDistance` solves f(lambda P) = 1 along the same ray instead (a few Halley steps on
/// log f, differentiable), giving d = |OP| (1 - lambda): the same sign and zero set, and metres
/// along the ray for every exponent. The per-instance cost stays eq. 5:
///   L_dist = 1/N sum sqrt(a1 a2 a3) d^2,
/// then eq. 7 adds L_coll (eq. 8: the mean over samples of j inside i) and L_floor (eq. 9: the
/// sum over samples below z = 0, as the paper writes it).

#include <array>
#include <optional>
#include <vector>

#include "simstack/geometry/superquadric.h"

namespace simstack {

struct FitConfig {
  double min_scale_m = 0.005;
  double max_scale_m = 0.4;
  double min_exponent = 1.0;    ///< >= 1 keeps shapes convex
  double max_exponent = 100.0;  ///< the generator's range
  double initial_exponent = 3.0;
  double lambda_dist = 100.0;  ///< eq. 7 weights (the paper's values)
  double lambda_coll = 10.0;
  double lambda_floor = 1.0;
  /// Points per instance in the per-instance fit's final solve: an even cover of the surface
  /// (one point per cell of a grid sized for this many cells).
  int max_points = 600;
  /// When the points surround the fitted shape (this share of the directions about its centre
  /// holds a point: a surface seen from all sides), `start_iterations` more steps take every
  /// point. Views of one side reach about half; above 1: never.
  double surrounded_share = 0.9;
  /// Points that do not surround the shape (a view of one side): eq. 5's volume weight,
  /// sqrt(a1 a2 a3), also pulls the unseen back of the shape toward the points by about
  /// noise^2 over how firmly the points hold the depth, so the final solve is followed by one
  /// with (a1 a2 a3)^one_sided_volume_exponent instead, kept when the volume grows by at most
  /// `one_sided_growth_limit` (where the points hardly hold the depth, the weaker weight lets
  /// the back drift away). 0.5 (the paper's weight): no second solve.
  double one_sided_volume_exponent = 0.125;
  double one_sided_growth_limit = 1.1;
  /// Points of the coarser cover on which the starts and the switched alternatives are tried.
  int coarse_points = 60;
  /// Points per instance in the joint refinement (every n-th of them).
  int joint_points = 100;
  int shape_samples = 200;  ///< surface samples per shape for the collision and floor terms
                            ///< (L_floor is a sum, so it grows with this)
  /// A collision or floor sample joins a joint round only when it is within this distance of
  /// penetrating at the round's start (the terms are hinges: farther samples add zeros).
  double contact_margin_m = 0.01;
  /// Joint solves; the collision and floor samples are redrawn and re-selected between them,
  /// so each round can catch penetrations the earlier samples missed.
  int joint_rounds = 10;
  int start_iterations = 10;      ///< Ceres iterations from each start or alternative (stage one)
  int max_iterations = 100;       ///< at most, for a solve to convergence (stage one)
  int joint_max_iterations = 10;  ///< Ceres iterations of each joint round
  int threads = 1;

  /// Throws std::invalid_argument naming the first field out of range.
  void validate() const;
};

/// Signed distance along the ray from the centre (see the file comment), metres, table frame.
double surfaceDistance(const SuperquadricShape& sq, const Vec3& p_table);

/// eq. 5 for one shape and its points.
double meanDistortion(const SuperquadricShape& sq, const Points3& points_table);

/// Oriented bounding box of the points (principal axes): centre, axes and half extents, with
/// exponents `initial_exponent`. Requires at least 4 points (std::invalid_argument).
SuperquadricShape initialGuess(const Points3& points_table, double initial_exponent = 3.0);

/// Stage one: fits one superquadric to the points of one instance (eqs. 5-6). Eq. 5 has many
/// local minima on partial and noisy views (and its global one is a point: the sqrt(a1 a2 a3)
/// weight shrinks faster than the distances grow), so the fit is a small search on
/// `coarse_points` of the points: short solves from the points' bounding box (with exponents
/// `initial_exponent`, 1.3 and 8), from two boxes reaching deeper behind the points, and from
/// `start` when given; the best that is not collapsed (a quarter of the points' extent at least)
/// solved to convergence; then its "switched" alternatives (each pair of axes turned by 45
/// degrees with the conjugate exponent, the passage between a box and a diamond cross-section
/// that a local solve cannot make), kept when better; last, a solve on `max_points`, and a few
/// steps on all points when they surround the shape (`surrounded_share`). The result is in
/// canonical form (canonicalSuperquadric). Points that do not surround the shape get a last
/// solve with a weaker volume weight (`one_sided_volume_exponent`).
SuperquadricShape fitSuperquadric(const Points3& points_table,
                                  const FitConfig& config = FitConfig(),
                                  const std::optional<SuperquadricShape>& start = std::nullopt);

/// Stage two: all shapes together with collision and floor penalties (eqs. 7-9).
/// `points_table[i]` belongs to `shapes[i]`.
std::vector<SuperquadricShape> refineJointly(const std::vector<Points3>& points_table,
                                             const std::vector<SuperquadricShape>& shapes,
                                             const FitConfig& config = FitConfig());

/// Points spanning more than this (m) are an object no fit may shrink away (collapsedFit).
constexpr double kCollapseSpanM = 0.02;
/// A joint refinement that leaves a shape below this share of its per-instance fit's volume
/// has pushed it out of its neighbours by shrinking it away: the per-instance fit stands, made
/// smaller until clear of them (fitInstances). The threshold lies in the gap between such
/// shapes and all others (docs/experiments.md, "Fitting").
constexpr double kLeastJointVolumeShare = 0.01;

/// True when `shape` is collapsed for `points_table`: the points span more than
/// kCollapseSpanM, and the shape's largest semi-axis is under a quarter of their oriented
/// box's (the degenerate basin of eq. 5, whose global minimum is a point).
bool collapsedFit(const SuperquadricShape& shape, const Points3& points_table);

/// Points whose smallest principal standard deviation is under this (m) lie on one plane (or
/// line) as exactly as noise-free depth makes them: eq. 5 is zero for every slab through them.
constexpr double kExactlyFlatM = 1e-4;

/// True when the points lie on one plane or line (their smallest principal standard deviation
/// under kExactlyFlatM). Measured points never do; rendered noise-free depth of a face does.
bool exactlyFlat(const Points3& points_table);

/// True when `shape` grew along exactlyFlat points: its box's half-extent along a principal
/// direction in which they spread passes 1.5 x their half-extent there plus 5 mm.
bool grownFit(const SuperquadricShape& shape, const Points3& points_table);

/// Stage one for a scene: fitSuperquadric for each point set of at least `min_points` points (in
/// parallel over `threads`; smaller sets and sets that cannot be fitted get std::nullopt), the
/// points' oriented box (initialGuess) where the fit collapses, flattens or grows (collapsedFit,
/// flattenedFit, grownFit).
std::vector<std::optional<SuperquadricShape>> fitEachInstance(const std::vector<Points3>& points,
                                                              const FitConfig& config,
                                                              int min_points = 30);

/// Stage two for a scene: the shapes of `fits` (std::nullopt: none) refined jointly with their
/// points, as fitInstances describes. std::invalid_argument when the counts differ.
void refineInstances(const std::vector<Points3>& points, const FitConfig& config,
                     std::vector<std::optional<SuperquadricShape>>* fits);

/// True when `shape` is flattened for `points_table`: a semi-axis at the fitter's lower bound
/// (at most 1.5 x `min_scale_m`) along which the middle 90 % of the points spans more than
/// kCollapseSpanM (a box fitted as a slab through it; a thin plate's points stay within its
/// thickness).
bool flattenedFit(const SuperquadricShape& shape, const Points3& points_table, double min_scale_m);

/// True when `shape` sits at the fitter's lower bound for an object seen larger: its largest
/// semi-axis is at most 1.5 x `config.min_scale_m` while `visible_table` (the depth points
/// measured on the object) spans more than kCollapseSpanM, or it is flattenedFit along one
/// axis for those points. No shipped fit should; the evaluations count them (`fits_at_bound`).
bool fitAtBound(const SuperquadricShape& shape, const Points3& visible_table,
                const FitConfig& config);

/// Both stages for a scene: per-instance fits (in parallel over `threads`), then, when
/// `joint`, the joint refinement of all fitted shapes. Sets with fewer than `min_points`
/// points are skipped (std::nullopt). No fit collapses: a per-instance fit that does
/// (collapsedFit, or flattenedFit along one axis), or grows past exactly flat points
/// (grownFit), is replaced by the points' oriented box (initialGuess), and a jointly refined
/// shape that does, whose points are exactlyFlat, or that keeps less than
/// kLeastJointVolumeShare of its per-instance fit's volume, by its per-instance fit scaled down
/// about its centre until clear of the others, but not below 0.3 of its points' extent, nor to the
/// bound along an axis they extend along.
std::vector<std::optional<SuperquadricShape>> fitInstances(const std::vector<Points3>& points,
                                                           const FitConfig& config, bool joint,
                                                           int min_points = 30);

/// Eq. 5's residuals as the solver evaluates them (weighted as for lambda = 1), and their
/// analytic Jacobian (row-major, 12 columns per point), at the solver's variables `u`: logits
/// of the three scales and three exponents within `config`'s bounds, then the translation and
/// the angle-axis vector of the shape's rotation. For the test of the Jacobian.
void distortionResiduals(const Points3& points_table, const FitConfig& config,
                         double volume_exponent, const std::array<double, 12>& u,
                         std::vector<double>* residuals, std::vector<double>* jacobian);

/// Mean squared penetration of `samples` surface samples of `b` into `a` (eq. 8 without
/// the weight), for reporting and tests.
double collisionCost(const SuperquadricShape& a, const SuperquadricShape& b, int samples = 400);

}  // namespace simstack
