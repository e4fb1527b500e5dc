#pragma once
/// @file scene_perception.h
/// The one entry point from depth to superquadrics (docs/design.md section 1), used by the tools,
/// the evaluation and the benchmarks:
///   depth (+ table pose, or a RANSAC table) -> partial TSDF -> C-VAE samples ->
///   Hough-voting instances -> marching cubes -> superquadric fits.
/// No torch and no ROS in this header.

#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "simstack/fitting/superquadric_fit.h"
#include "simstack/geometry/depth_view.h"
#include "simstack/geometry/image.h"
#include "simstack/geometry/pinhole_camera.h"
#include "simstack/geometry/triangle_mesh.h"
#include "simstack/geometry/voxel_grid.h"
#include "simstack/instances/surface_segments.h"
#include "simstack/model/cvae_config.h"
#include "simstack/model/model_integrity.h"
#include "simstack/pipeline/perception_config.h"
#include "simstack/pipeline/table_plane.h"

namespace simstack {

struct InstanceEstimate {
  SuperquadricShape superquadric;  ///< table frame
  TriangleMesh mesh;               ///< this instance's part of the predicted surface
  /// What was fitted: the views' depth points on the instance and samples of the part of
  /// `mesh` no view saw (PerceptionConfig::observed_points), or samples of `mesh`.
  Points3 points;
  /// The first this many of `points` are depth points the views measured on it (its seen
  /// surface, where a suction cup's seal is judged); 0 without observed_points.
  int measured_points = 0;
  /// Every depth point the views measured on it (at segments.pixel_stride), table frame: the
  /// surface a suction cup's seal is judged on. Empty without observed_points.
  Points3 measured;
  Vec3 vote_centre = Vec3::Zero();  ///< Hough centre
  int voxels = 0;
  /// Share of `mesh`'s area that the first view's camera sees (0..1): the rest was completed.
  double visible_fraction = 0.0;
  /// Its visible part in the first view reaches the image border (kTruncationBorderPx) or
  /// depth that was measured but left out (mask, workspace box, sensor range, the tiles of a
  /// pile cut at workspace.max_tiles or taller than a grid): the camera did not see where it
  /// ends, or the grid did not hold it, and its shape there is the network's guess.
  bool truncated = false;
};

/// Pixels from the image border within which a visible object counts as cut by it.
constexpr int kTruncationBorderPx = 2;

/// One generated scene: the network's grids and, when decomposed, its instances.
struct SceneHypothesis {
  Grid3<float> tsdf_m;
  Grid3<Vec3f> votes;
  Grid3<int> labels;     ///< instance per voxel, -1 free (empty unless decomposed)
  TriangleMesh surface;  ///< marching cubes of tsdf_m (made when decomposed)
  std::vector<InstanceEstimate> instances;
  bool decomposed = false;
};

struct StageTimings {
  double table_ms = 0, tsdf_ms = 0, network_ms = 0, instances_ms = 0, mesh_ms = 0, fitting_ms = 0,
         total_ms = 0;
};

struct SceneEstimate {
  Transform T_table_camera = Transform::Identity();  ///< of the first view
  bool table_estimated = false;  ///< true when the table came from RANSAC, not the caller
  GridSpec grid;  ///< the scene grid: one tile, or a cube holding all tiles (workspace.h)
  int tiles = 0;  ///< network passes this frame took (tiles, over both grids of a second pass)
  bool tiles_cropped = false;  ///< the pile needed more than workspace.max_tiles tiles
  double tile_side_m = 0.0;    ///< the side of the grid (or of each tile) perceived in
  /// The median over the first pass's instances of the cube root of their voxels (0 without
  /// instances): how large the objects looked to the network (GridConfig).
  double object_voxels = 0.0;
  double smallest_object_voxels = 0.0;          ///< the smallest of them (0 without instances)
  Grid3<float> partial_tsdf_m, partial_weight;  ///< the network's input, over the scene grid
  Grid3<float> occupancy_probability;           ///< share of hypotheses with tsdf <= 0, per voxel
  std::vector<SceneHypothesis> hypotheses;      ///< S of them; the decomposed ones first
  StageTimings timings;
  /// Instances of hypothesis 0 (the mean scene by default).
  const std::vector<InstanceEstimate>& instances() const { return hypotheses.front().instances; }
};

/// Depth points of a posed view in the table frame: the surface it measured, which the fits
/// take where the view saw an instance (PerceptionConfig::observed_points).
struct MeasuredView {
  PinholeCamera camera;
  Transform T_table_camera = Transform::Identity();
  Points3 points_table;
};

/// Splits one hypothesis into instances and fits them (Hough voting, marching cubes, Ceres).
/// With `segments` (the first view's convex patches, surface_segments.h) and
/// `config.segments.enabled`, instances are also split along the patches; with
/// `config.observed_points` the part of each instance that one of `measured_views` saw is
/// fitted to their depth points. `held`, in a second, finer pass, holds the first pass's
/// objects' depth points (one set per object), which vouch for the open containers joined within
/// surface_instances.held_container_profile_m and for the sides of an object seen past a nearer
/// one (held_occluded_plane_m). Adds the time spent to `timings` when given.
void decompose(SceneHypothesis* hypothesis, const PerceptionConfig& config,
               StageTimings* timings = nullptr, const SurfaceSegments* segments = nullptr,
               const std::vector<MeasuredView>& measured_views = {},
               const std::vector<Points3>& held = {});

/// The depth points of a view posed by `T_table_camera`, as the surface patches take them:
/// every `segments.pixel_stride`-th pixel of each row and column, at least `min_pile_height_m`
/// above the table and inside the box of `grid`.
MeasuredView measuredView(const DepthView& view, const Transform& T_table_camera,
                          const GridSpec& grid, const PerceptionConfig& config);

/// Instance of every pixel of `view` (posed by its own T_table_camera, else by the estimate's
/// first view's): the label of the labelled
/// voxel nearest to its table-frame point among the voxel holding it and its 26 neighbours
/// (observed points lie on the surface, which the prediction places up to a voxel off), then
/// made to follow the depth edges (followDepthEdges); -1 for table (points lower than
/// `min_height_m`), free space or missing depth.
Image<int> pixelInstances(const DepthView& view, const SceneEstimate& estimate, int hypothesis = 0,
                          double min_height_m = 0.005);

/// A spill: an instance's pixels in a depth-continuous region of the image (followDepthEdges)
/// that hold less than this share of the region, while the instance's main region is another.
constexpr double kSpillShare = 0.35;

/// Pixel labels (-1 none) made to follow the depth edges: labelled pixels are grouped into
/// depth-continuous regions (4-neighbours whose depths differ by at most 2 %), and an
/// instance's spill into a region not its own (kSpillShare) goes to that region's main
/// instance: the 2 cm voxels place an instance's edge up to a voxel across an occluding edge.
void followDepthEdges(const DepthImage& depth, Image<int>* labels);

/// The height above the table from which pixelInstances labels a pixel: half the pile's
/// threshold, so that the lowest centimetre of an object's side and a pot's floor are the
/// object's while the table's noise, which sets the pile's threshold, stays out.
inline double labelMinHeight(const PerceptionConfig& config) {
  return 0.5 * config.min_pile_height_m;
}

class ScenePerception {
 public:
  /// Loads the model; throws std::runtime_error naming the file when it cannot, and
  /// std::invalid_argument for a bad config value. An FC model has no latent space: it gets
  /// samples = 1 (see config()).
  explicit ScenePerception(const PerceptionConfig& config);
  ~ScenePerception();
  ScenePerception(const ScenePerception&) = delete;
  ScenePerception& operator=(const ScenePerception&) = delete;

  /// Several views must each carry a pose (they are fused in the table frame the poses share);
  /// a single view may leave the table to RANSAC. Throws std::invalid_argument for unusable
  /// input (no view, image and camera sizes differ, one of several views without pose) and
  /// std::runtime_error when no table pose is given and none can be estimated. A scene with nothing
  /// on the table gives hypotheses without instances. Calls from several threads run one at a time
  /// (one model state): for frames perceived in parallel, one ScenePerception per thread.
  SceneEstimate perceive(const std::vector<DepthView>& views) const;
  SceneEstimate perceive(const DepthView& view) const {
    return perceive(std::vector<DepthView>{view});
  }

  /// Perceives a rendered box (12 x 8 x 6 cm) on the table seen from 0.75 m, so that the first
  /// real frame does not pay for the network's first pass, and returns that estimate: a model
  /// that works finds one object there. Takes as long as one frame.
  SceneEstimate warmUp() const;

  /// Replaces the settings, keeping the model and the thread count (std::invalid_argument for
  /// another model or thread count, or a bad value; the settings in use then stay). Waits for a
  /// perceive() under way on another thread; the next one uses the new settings. config()'s
  /// reference is not to be read beside it.
  void updateSettings(const PerceptionConfig& config);
  /// The settings updateSettings(config) would put in effect (an FC model's single sample; a
  /// C-VAE's decompose_samples lowered to samples when above it), changing nothing; throws
  /// std::invalid_argument where it would. Safe beside a perceive() or updateSettings() on another
  /// thread: it reads only what those never change.
  PerceptionConfig settingsInEffect(const PerceptionConfig& config) const;

  const PerceptionConfig& config() const;
  const CvaeConfig& modelConfig() const;

 private:
  /// The tiles of side `side_m` covering the pile `view` shows (`config` scaled to the side).
  TilePlan planGrid(const DepthView& view, const Transform& T_table_camera, double side_m,
                    const PerceptionConfig& config) const;
  /// One pass of perceive() over `plan`'s tiles of side `side_m` (`config` scaled to it), into
  /// `estimate`, which holds the table pose; times and tiles add to what it has. `held`: the
  /// first pass's objects' depth points in a second pass (decompose), else empty.
  void perceiveInGrid(const std::vector<DepthView>& views,
                      const std::vector<DepthView>& views_given, const TilePlan& plan,
                      double side_m, const PerceptionConfig& config,
                      const std::vector<Points3>& held, SceneEstimate* estimate) const;

  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// The tile side of perceive()'s last pass (GridConfig): `side_m`, the first pass's, unless the
/// first pass's objects (`object_voxels`, the median over them of the cube root of their voxels;
/// 0 without objects) look smaller than `grid.object_voxels`, or the smallest of them
/// (`smallest_voxels`) smaller than `grid.smallest_object_voxels`; then grid.fine_side_share of
/// it. (perceive() takes the finer side only with segments.enabled.)
double gridSideFor(const GridConfig& grid, double side_m, double object_voxels,
                   double smallest_voxels);

/// A model's self-test: what the pipeline's defaults (one sample, one network pass, the default
/// Hough setting, none of the model card's; one grid, no finer second pass) perceive with it on
/// warmUp()'s rendered box.
struct ModelSelfTest {
  int objects = 0;
  int occupied_voxels = 0;  ///< occupancy probability >= 0.5
};
ModelSelfTest runModelSelfTest(const std::string& model_path);

/// Checks the model at `model_path` as every loader does (its card's SHA-256 and format, finite
/// weights), then runs the self-test and compares it with the card's `integrity.self_test`: the
/// same object count, and occupied voxels within 5 % (a few voxels for a small count). Returns
/// the self-test's result; throws std::runtime_error naming the model and what failed (nothing
/// is compared when the card records no self-test).
ModelSelfTest checkModel(const std::string& model_path);
/// Records the model file's SHA-256, format and self-test in its card's `integrity:` section
/// (after training, or after replacing the file on purpose) and returns them; the weights must
/// be finite. std::runtime_error naming the file when it cannot be read, fails to load or the
/// card cannot be written; the card is then left as it was.
ModelIntegrity stampModel(const std::string& model_path);

/// Throws std::invalid_argument as perceive() would for this single view: its size, camera,
/// pose or mask, or no depth within `config`'s sensor range (for tools that pass a view on).
void checkPerceivableView(const DepthView& view, const PerceptionConfig& config);

}  // namespace simstack
