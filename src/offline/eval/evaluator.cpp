#include "simstack/offline/eval/evaluator.h"

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <random>
#include <set>
#include <sstream>
#include <stdexcept>

#include "simstack/fitting/superquadric_fit.h"
#include "simstack/offline/dataset/ground_truth.h"
#include "simstack/offline/dataset/viewpoints.h"
#include "simstack/offline/eval/occupancy.h"
#include "simstack/offline/eval/scene_metrics.h"
#include "simstack/render/depth_renderer.h"

namespace simstack {
namespace {

using nlohmann::json;

const std::vector<double> kBinEdges = {0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 1.01};
const std::vector<std::string> kMetrics = {
    "chamfer_visible_m", "chamfer_full_m", "chamfer_full_sq_m", "iou",         "bce",
    "displacement_m",    "stable",         "count_error",       "count_exact", "count_exact_seen",
    "fits_at_bound"};

double mean(const std::vector<double>& v) {
  double s = 0;
  for (double x : v) s += x;
  return v.empty() ? std::nan("") : s / v.size();
}
double stddev(const std::vector<double>& v) {
  const double m = mean(v);
  double s = 0;
  for (double x : v) s += (x - m) * (x - m);
  return v.size() > 1 ? std::sqrt(s / (v.size() - 1)) : std::nan("");  // null in the JSON
}
std::vector<double> finiteValues(const std::vector<Row>& rows, const std::string& metric) {
  std::vector<double> v;
  for (const Row& r : rows)
    if (r.count(metric) && std::isfinite(r.at(metric))) v.push_back(r.at(metric));
  return v;
}

/// The per-view rows, their indices and counts as whole numbers.
json rowsJson(const std::vector<Row>& rows) {
  static const std::set<std::string> kWhole = {"scene",        "view",  "objects",
                                               "objects_seen", "count", "fits_at_bound"};
  json out = json::array();
  for (const Row& r : rows) {
    json row = json::object();
    for (const auto& [key, value] : r)
      if (kWhole.count(key) && std::isfinite(value))
        row[key] = static_cast<long long>(std::llround(value));
      else
        row[key] = value;
    out.push_back(std::move(row));
  }
  return out;
}

/// One scene's ground truth for the protocol: the true surface, and its samples.
struct SceneTruth {
  TriangleMesh mesh;
  Points3 full;  ///< samples of the whole true surface
};

/// One rendered view (and the further views of the multi-view protocol) and its ground truth
/// on the visible side.
struct ViewTruth {
  std::vector<DepthView> views;  ///< the protocol's view first
  Transform T_table_camera;
  Points3 visible;  ///< samples of the visible true surface
  double visible_ratio = 0;
  int objects_seen = 0;  ///< true objects with at least EvaluationOptions::seen_pixels
};

/// The scores of one method's estimate of one view.
void scoreEstimate(const MethodEstimate& est, const SceneRecord& rec, const SceneTruth& scene,
                   const ViewTruth& vt, const GroundTruthGrids& gt,
                   const EvaluationOptions& options, std::mt19937_64& rng, Row* row) {
  const PinholeCamera& camera = vt.views.front().camera;
  const int points = options.chamfer_points;
  double full = 0, visible = 0;
  for (const TriangleMesh& surface : est.surfaces) {
    full += chamferDistance(samplePoints(surface, points, rng), scene.full);
    visible += chamferDistance(
        samplePoints(subMesh(surface, visibleTriangles(surface, camera, vt.T_table_camera)), points,
                     rng),
        vt.visible);
  }
  (*row)["chamfer_full_m"] = full / est.surfaces.size();
  (*row)["chamfer_visible_m"] = visible / est.surfaces.size();
  if (std::isfinite(est.perceive_ms)) (*row)["perceive_ms"] = est.perceive_ms;
  if (std::isfinite(est.grid_side_m)) (*row)["grid_side_m"] = est.grid_side_m;
  if (std::isfinite(est.object_voxels)) (*row)["object_voxels"] = est.object_voxels;
  if (std::isfinite(est.smallest_object_voxels))
    (*row)["smallest_object_voxels"] = est.smallest_object_voxels;
  const OccupancyScores sc = scoreOccupancy(gt.tsdf.data, est.hypotheses_tsdf);
  (*row)["iou"] = sc.iou;
  (*row)["bce"] = sc.bce;
  if (!est.objects) return;
  const std::vector<SuperquadricShape>& shapes = est.superquadrics;
  (*row)["chamfer_full_sq_m"] =
      chamferDistance(samplePoints(superquadricsMesh(shapes), points, rng), scene.full);
  const double objects = static_cast<double>(rec.scene.objects.size());
  (*row)["count"] = shapes.size();
  (*row)["count_error"] = std::abs(static_cast<double>(shapes.size()) - objects);
  (*row)["count_exact"] = shapes.size() == rec.scene.objects.size();
  (*row)["count_exact_seen"] = static_cast<int>(shapes.size()) == vt.objects_seen;
  if (est.fits_at_bound) (*row)["fits_at_bound"] = *est.fits_at_bound;
  if (options.stability && !shapes.empty()) {
    const StabilityResult st = simulateStability(shapes);
    (*row)["displacement_m"] = st.mean_displacement_m;
    (*row)["stable"] = st.stable;
  }
}

/// The true objects that at least `min_pixels` pixels of the rendered view see with a valid
/// depth (after the noise's dropouts).
int objectsSeen(const RenderResult& r, int objects, int min_pixels) {
  std::vector<int> pixels(static_cast<size_t>(objects) + 1, 0);
  for (size_t i = 0; i < r.instances.pixels.size(); ++i) {
    const int id = r.instances.pixels[i];
    if (id >= 1 && id <= objects && validDepth(r.depth.pixels[i])) ++pixels[id];
  }
  return static_cast<int>(
      std::count_if(pixels.begin() + 1, pixels.end(), [&](int n) { return n >= min_pixels; }));
}

/// Every method on view `v` of scene `k`. Separate random streams per scene, per view and per
/// method: the views, and each method's Chamfer samples, do not depend on which other methods
/// are in the run.
void evaluateView(const SceneRecord& rec, int k, int v, const SceneTruth& scene,
                  const DepthRenderer& renderer, uint64_t scene_seed, const PinholeCamera& camera,
                  double truncation_vox, const std::vector<EvaluatedMethod*>& methods,
                  const EvaluationOptions& options, std::vector<MethodResults>* results) {
  std::mt19937_64 rng(scene_seed + 7919ull * static_cast<uint64_t>(v + 1));
  ViewTruth vt;
  vt.T_table_camera =
      sampleViewpoint(rec.scene.surfaceCentroid(),
                      options.overhead ? ViewpointRange::overhead() : ViewpointRange(), rng);
  const uint64_t view_seed = rng();
  const RenderResult r = renderer.render(
      camera, vt.T_table_camera,
      options.noise ? SensorNoiseConfig::preset(options.sensor, view_seed) : SensorNoiseConfig());
  std::vector<bool> seen = visibleTriangles(scene.mesh, camera, vt.T_table_camera);
  vt.visible = samplePoints(subMesh(scene.mesh, seen), options.chamfer_points, rng);
  vt.views = {DepthView{r.depth, camera, vt.T_table_camera}};
  vt.objects_seen = objectsSeen(r, static_cast<int>(rec.scene.objects.size()), options.seen_pixels);
  // The further views turn the first about the vertical through the pile's centre; their
  // noise has its own stream, so the first view is the single-view protocol's.
  const Vec3 centre = rec.scene.surfaceCentroid();
  for (int j = 1; j < options.views_per_estimate; ++j) {
    const double angle = 2.0 * M_PI * j / options.views_per_estimate;
    const Transform T = Eigen::Translation3d(centre) * Eigen::AngleAxisd(angle, Vec3::UnitZ()) *
                        Eigen::Translation3d(-centre) * vt.T_table_camera;
    const uint64_t noise_seed = view_seed ^ (0x9e3779b97f4a7c15ull * static_cast<uint64_t>(j));
    vt.views.push_back(
        DepthView{renderer
                      .render(camera, T,
                              options.noise ? SensorNoiseConfig::preset(options.sensor, noise_seed)
                                            : SensorNoiseConfig())
                      .depth,
                  camera, T});
    const std::vector<bool> also = visibleTriangles(scene.mesh, camera, T);
    for (size_t t = 0; t < seen.size(); ++t) seen[t] = seen[t] || also[t];
  }
  vt.visible_ratio = subMesh(scene.mesh, seen).area() / scene.mesh.area();
  std::optional<GridSpec> first;  // the first method's grid, handed to the others
  GridSpec grid;                  // the ground truth's
  GroundTruthGrids gt;
  const uint64_t method_seed = rng();
  for (size_t i = 0; i < methods.size(); ++i) {
    std::mt19937_64 method_rng(method_seed ^ std::hash<std::string>{}(methods[i]->name()));
    Row row{{"scene", k},
            {"view", v},
            {"visible_ratio", vt.visible_ratio},
            {"objects", static_cast<double>(rec.scene.objects.size())},
            {"objects_seen", static_cast<double>(vt.objects_seen)}};
    const MethodEstimate est = methods[i]->estimateViews(vt.views, first ? &*first : nullptr,
                                                         rec.scene.surfaceCentroid().head<2>());
    // Each estimate is scored on its own grid (a network may perceive a view in a finer grid,
    // GridConfig); a method that takes the grid it is handed (the classical baseline) gets the
    // first method's. The truncation keeps the dataset's voxels.
    if (!first || !(est.grid == grid)) {
      grid = est.grid;
      gt = computeGroundTruth(rec.scene, grid, truncation_vox * grid.voxel_size_m);
    }
    if (!first) first = est.grid;
    scoreEstimate(est, rec, scene, vt, gt, options, method_rng, &row);
    (*results)[i].rows.push_back(std::move(row));
  }
}

std::string fixed(double value, int digits) {
  std::ostringstream o;
  o << std::fixed << std::setprecision(digits) << value;
  return o.str();
}

}  // namespace

MethodEstimate EvaluatedMethod::estimateViews(const std::vector<DepthView>& views,
                                              const GridSpec* grid, const Vec2& pile_xy) {
  if (views.size() != 1)
    throw std::invalid_argument(name() + " takes one view, not " + std::to_string(views.size()));
  return estimate(views.front(), grid, pile_xy);
}

EvaluationResults evaluateDataset(const DatasetReader& reader,
                                  const std::vector<EvaluatedMethod*>& methods,
                                  const EvaluationOptions& options,
                                  const std::function<void(int, int)>& progress) {
  EvaluationResults out;
  out.options = options;
  out.dataset = reader.info();
  out.scenes = options.scenes > 0 ? std::min(options.scenes, reader.size()) : reader.size();
  if (options.views_per_estimate < 1)
    throw std::invalid_argument("views_per_estimate must be >= 1, not " +
                                std::to_string(options.views_per_estimate));
  for (EvaluatedMethod* m : methods) out.methods.push_back({m->name(), m->info(), {}});
  const PinholeCamera camera =
      options.camera ? *options.camera : scaledKinect(options.width, options.height);
  camera.validate();
  for (int k = 0; k < out.scenes; ++k) {
    const SceneRecord rec = reader.read(k);
    if (options.stability) {
      // The true piles under the same test: the reference for the methods' rows (the generator
      // verified them at rest for one second; the test runs 42 s).
      const StabilityResult st = simulateStability(rec.scene);
      out.truth_stable.push_back(st.stable);
      out.truth_displacement_m.push_back(st.mean_displacement_m);
    }
    const DepthRenderer renderer(rec.scene);
    SceneTruth scene;
    for (const SceneObject& o : rec.scene.objects)
      scene.mesh.append(o.shape->mesh().transformed(o.T_table_object));
    std::mt19937_64 scene_rng(options.seed * 1000003ull + static_cast<uint64_t>(k));
    scene.full = samplePoints(scene.mesh, options.chamfer_points, scene_rng);
    const uint64_t scene_seed = scene_rng();
    for (int v = 0; v < options.views; ++v)
      evaluateView(rec, k, v, scene, renderer, scene_seed, camera,
                   reader.info().truncation_m * reader.info().resolution / reader.info().extent_m,
                   methods, options, &out.methods);
    if (progress) progress(k + 1, out.scenes);
  }
  return out;
}

json summarise(const std::vector<Row>& rows) {
  json out;
  for (const auto& m : kMetrics) {
    const std::vector<double> v = finiteValues(rows, m);
    out[m] = {{"mean", mean(v)}, {"std", stddev(v)}, {"n", v.size()}};
  }
  json bins = json::array();
  for (size_t b = 0; b + 1 < kBinEdges.size(); ++b) {
    std::vector<Row> in;
    for (const Row& r : rows)
      if (r.at("visible_ratio") >= kBinEdges[b] && r.at("visible_ratio") < kBinEdges[b + 1])
        in.push_back(r);
    json bin = {{"visible_from", kBinEdges[b]},
                {"visible_to", std::min(kBinEdges[b + 1], 1.0)},
                {"views", in.size()}};
    for (const auto& m : kMetrics) bin[m] = mean(finiteValues(in, m));
    bins.push_back(bin);
  }
  out["by_visible_ratio"] = bins;
  return out;
}

json resultsJson(const EvaluationResults& r, bool with_views) {
  const EvaluationOptions& o = r.options;
  json out;
  out["dataset_seed"] = r.dataset.seed;
  out["scenes"] = r.scenes;
  out["views"] = o.views;
  out["seed"] = o.seed;
  if (o.camera) {
    out["image"] = std::to_string(o.camera->width) + "x" + std::to_string(o.camera->height);
    out["intrinsics"] = {o.camera->fx, o.camera->fy, o.camera->cx, o.camera->cy};
  } else {
    out["image"] = std::to_string(o.width) + "x" + std::to_string(o.height);
  }
  out["noise"] = o.noise;
  if (o.noise) out["sensor"] = sensorModelName(o.sensor);
  out["overhead"] = o.overhead;
  out["views_per_estimate"] = o.views_per_estimate;
  out["chamfer_points"] = o.chamfer_points;
  out["seen_pixels"] = o.seen_pixels;
  if (!r.truth_stable.empty())
    out["ground_truth"] = {{"stable", mean(r.truth_stable)},
                           {"displacement_m", mean(r.truth_displacement_m)}};
  for (const MethodResults& m : r.methods) {
    json j = summarise(m.rows);
    j["model"] = m.info.model;
    j["samples"] = m.info.samples;
    if (!m.info.config_yaml.empty()) j["config"] = m.info.config_yaml;
    if (with_views) j["views"] = rowsJson(m.rows);
    out["methods"][m.name] = j;
  }
  return out;
}

std::string resultsTable(const EvaluationResults& r) {
  std::ostringstream o;
  o << "| method | CD visible (mm) | CD full (mm) | CD full, superquadrics (mm) | IoU | BCE "
       "| displacement (mm) | stable | count exact |\n|---|---|---|---|---|---|---|---|---|\n";
  for (const MethodResults& m : r.methods) {
    const json s = summarise(m.rows);
    auto val = [&](const char* key, double scale, int digits) {
      const double v = s[key]["mean"].get<double>();
      return std::isfinite(v) ? fixed(v * scale, digits) : std::string("-");
    };
    auto percent = [&](const char* key) {
      const std::string v = val(key, 100, 0);
      return v == "-" ? v : v + " %";
    };
    o << "| " << m.name << " | " << val("chamfer_visible_m", 1000, 1) << " | "
      << val("chamfer_full_m", 1000, 1) << " | " << val("chamfer_full_sq_m", 1000, 1) << " | "
      << val("iou", 1, 3) << " | " << val("bce", 1, 3) << " | " << val("displacement_m", 1000, 1)
      << " | " << percent("stable") << " | " << percent("count_exact") << " |\n";
  }
  bool first = true;
  for (const MethodResults& m : r.methods) {
    const std::vector<double> v = finiteValues(m.rows, "fits_at_bound");
    if (v.empty()) continue;  // a method that keeps no measured points per object
    double total = 0;
    for (double x : v) total += x;
    o << (first ? "\n" : "") << m.name << ": " << fixed(total, 0)
      << " superquadrics at the fitter's lower bound for objects seen over "
      << fixed(100 * kCollapseSpanM, 0) << " cm, in " << v.size() << " views\n";
    first = false;
  }
  if (!r.truth_stable.empty())
    o << "\nthe true piles under the same stability test: " << fixed(100 * mean(r.truth_stable), 0)
      << " % stable, mean displacement " << fixed(1000 * mean(r.truth_displacement_m), 1)
      << " mm\n";
  return o.str();
}

}  // namespace simstack
