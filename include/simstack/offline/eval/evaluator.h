#pragma once
/// @file evaluator.h
/// The evaluation protocol of docs/design.md section 6 (the paper's section 4.1, Table 1) over one
/// interface that every evaluated method implements (the networks through ScenePerception, the
/// classical baseline; see offline/eval/evaluated_methods.h): each test scene seen from random
/// viewpoints in the paper's ranges, every method on the same rendered views, scored by
/// visible and full Chamfer distance, expected occupancy (BCE, IoU), stability of the fitted
/// superquadrics under physics and object counts, binned by the visible share of the surface.
/// The labelled real scenes are evaluated in real_scenes.h.

#include <functional>
#include <limits>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "simstack/geometry/depth_view.h"
#include "simstack/geometry/superquadric.h"
#include "simstack/geometry/triangle_mesh.h"
#include "simstack/geometry/voxel_grid.h"
#include "simstack/offline/dataset/dataset.h"
#include "simstack/offline/dataset/viewpoints.h"
#include "simstack/render/depth_renderer.h"

namespace simstack {

/// What a method gives the evaluation for one view.
struct MethodEstimate {
  GridSpec grid;                       ///< the grid `hypotheses_tsdf` lie on
  std::vector<TriangleMesh> surfaces;  ///< the predicted full surface of each hypothesis
  std::vector<std::vector<float>> hypotheses_tsdf;  ///< per hypothesis on `grid`; <= 0 occupied
  std::vector<SuperquadricShape> superquadrics;     ///< the objects found, table frame
  /// Per object, the depth points measured on it (table frame; empty when the method keeps
  /// none): where a grasp's seal is judged.
  std::vector<Points3> measured_surfaces;
  /// The camera that measured them, when one did (table frame).
  std::optional<Vec3> measured_from;
  /// Objects whose superquadric sits at the fitter's lower bound though the camera saw them
  /// larger (fitAtBound on their measured points); none for a method that keeps no measured
  /// points per object.
  std::optional<int> fits_at_bound;
  /// The objects of the further hypotheses that were decomposed (robust grasp ranking).
  std::vector<std::vector<SuperquadricShape>> further_superquadrics;
  Image<int> pixel_instances;  ///< instance per pixel of the view, -1 none (may stay empty)
  bool table_estimated = false;
  /// False for a method that finds no objects (TSDF fusion): no object metrics are scored.
  bool objects = true;
  double perceive_ms = std::numeric_limits<double>::quiet_NaN();
  /// The network's grid side, and how large the first pass's objects looked in voxels, at the
  /// median and the smallest (SceneEstimate::tile_side_m, object_voxels,
  /// smallest_object_voxels); NaN for a method without a network.
  double grid_side_m = std::numeric_limits<double>::quiet_NaN();
  double object_voxels = std::numeric_limits<double>::quiet_NaN();
  double smallest_object_voxels = std::numeric_limits<double>::quiet_NaN();
};

/// Provenance of a method, for the results file.
struct MethodInfo {
  std::string model;        ///< model file ("" for the classical baseline)
  int samples = 1;          ///< hypotheses per view
  std::string config_yaml;  ///< its perception config ("" when it has none)
};

class EvaluatedMethod {
 public:
  virtual ~EvaluatedMethod() = default;
  /// Unique within a run: it also seeds the method's Chamfer samples.
  virtual const std::string& name() const = 0;
  virtual MethodInfo info() const = 0;
  /// The method's estimate for `view` (whose pose is known). `grid`: the grid the run's first
  /// method chose for the view, for a method that takes one (the classical baseline, TSDF
  /// fusion), else nullptr. The ground truth follows the grid of each estimate, so a method may
  /// also choose its own (a network's `grid:` side). `pile_xy`: the true pile's x/y centre, for
  /// a method that needs a grid without choosing one itself.
  virtual MethodEstimate estimate(const DepthView& view, const GridSpec* grid,
                                  const Vec2& pile_xy) = 0;
  /// The estimate from several posed views of one scene, `views[0]` the reference view (the
  /// multi-view protocol, EvaluationOptions::views_per_estimate). This default takes one
  /// view (std::invalid_argument for more).
  virtual MethodEstimate estimateViews(const std::vector<DepthView>& views, const GridSpec* grid,
                                       const Vec2& pile_xy);
};

struct EvaluationOptions {
  int views = 3;                  ///< random viewpoints per scene
  int scenes = 0;                 ///< the first N scenes (0 = all)
  uint64_t seed = 7;              ///< viewpoints and Chamfer samples
  int width = 640, height = 480;  ///< rendered image (a scaled Kinect)
  /// The rendered camera instead of a Kinect scaled to width x height (another sensor's
  /// intrinsics; the noise is `sensor`'s).
  std::optional<PinholeCamera> camera;
  bool noise = false;                        ///< sensor noise in the rendered views
  SensorModel sensor = SensorModel::kinect;  ///< whose noise (SensorNoiseConfig::preset)
  bool stability = true;                     ///< the physics stability test
  int chamfer_points = 1000;                 ///< surface samples per Chamfer set
  /// A true object counts as seen when this many pixels of the protocol's view see it with a
  /// valid depth: `count_exact_seen` compares the count with the objects seen (an object behind
  /// others may show a handful of pixels, or none).
  int seen_pixels = 100;
  bool overhead = false;  ///< views from above (ViewpointRange::overhead())
  /// Posed views per estimate (the paper's multi-view experiment): the first drawn as in the
  /// single-view protocol (the same view and noise), the others that viewpoint turned about
  /// the vertical through the pile's centre by 360 / views_per_estimate degrees each. Visible
  /// shares count what any of them sees; the visible Chamfer stays the first view's.
  int views_per_estimate = 1;
};

using Row = std::map<std::string, double>;
struct MethodResults {
  std::string name;
  MethodInfo info;
  /// One per view: scene, view, visible_ratio, objects, objects_seen, the metrics.
  std::vector<Row> rows;
};
struct EvaluationResults {
  EvaluationOptions options;
  DatasetInfo dataset;
  int scenes = 0;
  std::vector<MethodResults> methods;
  std::vector<double> truth_stable, truth_displacement_m;  ///< the true piles, per scene
};

/// Runs every method on every view of the dataset's first `options.scenes` scenes (the same
/// views for all). `progress(done, total)` is called after each scene.
EvaluationResults evaluateDataset(const DatasetReader& reader,
                                  const std::vector<EvaluatedMethod*>& methods,
                                  const EvaluationOptions& options,
                                  const std::function<void(int, int)>& progress = {});

/// Means, standard deviations and counts of each metric, and the means binned by the visible
/// share of the pile's surface.
nlohmann::json summarise(const std::vector<Row>& rows);
/// The results file: the options, the true piles' stability and, per method, its summary and
/// provenance; with `with_views` also every view's row.
nlohmann::json resultsJson(const EvaluationResults& results, bool with_views);
/// The table the tool prints (GitHub markdown).
std::string resultsTable(const EvaluationResults& results);

}  // namespace simstack
