#include "simstack/offline/eval/evaluated_methods.h"

#include <algorithm>
#include <chrono>
#include <filesystem>

#include "simstack/mesh/marching_cubes.h"
#include "simstack/offline/eval/scene_metrics.h"
#include "simstack/pipeline/scene_perception.h"
#include "simstack/pipeline/table_plane.h"
#include "simstack/seeds.h"
#include "simstack/tsdf/network_input.h"
#include "simstack/tsdf/projective_tsdf.h"

namespace simstack {

NetworkMethod::NetworkMethod(const PerceptionConfig& config, bool label_pixels)
    : label_pixels_(label_pixels), base_seed_(config.seed) {
  perception_ = std::make_unique<ScenePerception>(config);
  name_ = architecture();
}

NetworkMethod::~NetworkMethod() = default;

const std::string& NetworkMethod::architecture() const {
  return perception_->modelConfig().architecture;
}

namespace {

/// A path as a results file records it: relative to the working directory when it lies below
/// it, so that results written from checkouts in different places compare equal.
std::string recordedPath(const std::string& path) {
  std::error_code ec;
  const std::filesystem::path relative = std::filesystem::proximate(path, ec);
  if (ec || relative.empty() || *relative.begin() == "..") return path;
  return relative.string();
}

}  // namespace

MethodInfo NetworkMethod::info() const {
  PerceptionConfig c = perception_->config();
  c.model_path = recordedPath(c.model_path);
  c.seed = base_seed_;  // each estimate's code seed is drawn from it
  return {c.model_path, c.samples, perceptionYaml(c)};
}

MethodEstimate NetworkMethod::estimate(const DepthView& view, const GridSpec* grid,
                                       const Vec2& pile_xy) {
  return estimateViews({view}, grid, pile_xy);
}

MethodEstimate NetworkMethod::estimateViews(const std::vector<DepthView>& views, const GridSpec*,
                                            const Vec2&) {
  // The protocol draws S prior codes for every view, not one draw for the whole run: the n-th
  // estimate of a model with a code gets its own seed (the same in every run of the same
  // views). A model without a code keeps the config's seed.
  if (perception_->modelConfig().hasLatentCode()) {
    PerceptionConfig c = perception_->config();
    c.seed = splitMix64(base_seed_ + 0x9E3779B97F4A7C15ull * ++estimates_);
    perception_->updateSettings(c);
  }
  const SceneEstimate est = perception_->perceive(views);
  MethodEstimate out;
  out.grid = est.grid;
  for (const SceneHypothesis& h : est.hypotheses) {
    out.hypotheses_tsdf.push_back(h.tsdf_m.data);
    out.surfaces.push_back(h.surface.empty() ? extractSurface(h.tsdf_m) : h.surface);
  }
  if (views.size() == 1) out.measured_from = est.T_table_camera.translation();
  out.fits_at_bound = 0;
  for (const InstanceEstimate& e : est.instances()) {
    out.superquadrics.push_back(e.superquadric);
    out.measured_surfaces.push_back(e.measured);
    *out.fits_at_bound +=
        fitAtBound(e.superquadric, Points3(e.points.begin(), e.points.begin() + e.measured_points),
                   perception_->config().fit);
  }
  for (size_t h = 1; h < est.hypotheses.size() && est.hypotheses[h].decomposed; ++h) {
    out.further_superquadrics.emplace_back();
    for (const InstanceEstimate& e : est.hypotheses[h].instances)
      out.further_superquadrics.back().push_back(e.superquadric);
  }
  if (label_pixels_)
    out.pixel_instances =
        pixelInstances(views.front(), est, 0, labelMinHeight(perception_->config()));
  out.table_estimated = est.table_estimated;
  out.perceive_ms = est.timings.total_ms;
  out.grid_side_m = est.tile_side_m;
  out.object_voxels = est.object_voxels;
  out.smallest_object_voxels = est.smallest_object_voxels;
  return out;
}

ClassicalMethod::ClassicalMethod(const ClassicalConfig& config, double extent_m, int resolution,
                                 bool label_pixels)
    : config_(config), extent_m_(extent_m), resolution_(resolution), label_pixels_(label_pixels) {
  if (label_pixels_) config_.pixel_stride = 1;
}

MethodEstimate ClassicalMethod::estimate(const DepthView& view, const GridSpec* grid,
                                         const Vec2& pile_xy) {
  const auto start = std::chrono::steady_clock::now();
  MethodEstimate out;
  out.table_estimated = !view.T_table_camera;
  const Transform T = view.T_table_camera
                          ? *view.T_table_camera
                          : estimateTablePlane(view.depth, view.camera).T_table_camera;
  if (grid) {
    out.grid = *grid;
  } else {  // the grid a network would use, for the occupancy scores
    const Vec2 c = visiblePileCentre(view.depth, view.camera, T, pile_xy, 0.5 * extent_m_);
    out.grid = GridSpec::sceneGrid(c, extent_m_, resolution_);
  }
  // A real scene is taken whole (its pile may be wider than one grid).
  out.superquadrics =
      classicalBaseline(view.depth, view.camera, T, config_, label_pixels_ ? nullptr : &out.grid,
                        label_pixels_ ? &out.pixel_instances : nullptr);
  out.hypotheses_tsdf.push_back(superquadricOccupancy(out.superquadrics, out.grid));
  out.surfaces.push_back(superquadricsMesh(out.superquadrics));
  out.perceive_ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  return out;
}

FusionMethod::FusionMethod(double extent_m, int resolution, double truncation_m)
    : extent_m_(extent_m), resolution_(resolution), truncation_m_(truncation_m) {}

MethodEstimate FusionMethod::estimate(const DepthView& view, const GridSpec* grid,
                                      const Vec2& pile_xy) {
  return estimateViews({view}, grid, pile_xy);
}

MethodEstimate FusionMethod::estimateViews(const std::vector<DepthView>& views,
                                           const GridSpec* grid, const Vec2& pile_xy) {
  MethodEstimate out;
  out.objects = false;
  out.grid = grid ? *grid : GridSpec::sceneGrid(pile_xy, extent_m_, resolution_);
  ProjectiveTsdfConfig tc;
  tc.truncation_m = truncation_m_;
  ProjectiveTsdf fused(out.grid, tc);
  for (const DepthView& v : views) {
    if (!v.T_table_camera) throw std::invalid_argument("fusion: every view needs its pose");
    fused.integrate(v.depth, v.camera, *v.T_table_camera);
  }
  Grid3<float> tsdf = fused.tsdf();
  const Grid3<float>& weight = fused.weight();
  for (size_t i = 0; i < tsdf.data.size(); ++i)
    if (!(weight.data[i] > 0.0f)) tsdf.data[i] = static_cast<float>(truncation_m_);
  out.surfaces.push_back(extractSurface(tsdf));
  out.hypotheses_tsdf.push_back(std::move(tsdf.data));
  return out;
}

std::vector<std::unique_ptr<EvaluatedMethod>> multiViewMethods(
    const std::vector<PerceptionConfig>& configs, int refine_iterations, double extent_m,
    int resolution, double truncation_m) {
  std::vector<std::unique_ptr<EvaluatedMethod>> methods;
  std::vector<std::string> bases;  // each config's name: its architecture, indexed when repeated
  for (size_t i = 0; i < configs.size(); ++i) {
    bool has_code = true;  // known from the first method made of this config
    for (const std::string condition : {"all", "first"}) {
      for (const bool optimise : {false, true}) {
        // As ScenePerception decides: fitted codes, or more prior draws than kept.
        const bool codes_from_views =
            refine_iterations > 0 || configs[i].refine_starts > configs[i].samples;
        if (optimise && (!codes_from_views || !has_code)) continue;
        PerceptionConfig c = configs[i];
        c.zero_code_first = false;  // random codes, as the paper evaluates
        c.condition_views = condition;
        c.refine_iterations = optimise ? refine_iterations : 0;
        if (!optimise) c.refine_starts = 0;
        auto m = std::make_unique<NetworkMethod>(c);
        has_code = m->architecture() == "cvae";
        if (bases.size() == i) {
          const bool repeated =
              std::find(bases.begin(), bases.end(), m->architecture()) != bases.end();
          bases.push_back(m->architecture() + (repeated ? "_" + std::to_string(i) : ""));
        }
        std::string name = bases[i];
        if (condition == "first") name += "_first";
        if (optimise) name += "_opt";
        m->rename(name);
        methods.push_back(std::move(m));
      }
    }
  }
  const bool refined = std::any_of(methods.begin(), methods.end(), [](const auto& m) {
    const std::string& n = m->name();
    return n.size() > 4 && n.compare(n.size() - 4, 4, "_opt") == 0;
  });
  if (refine_iterations > 0 && !refined) {
    std::string names;
    for (const std::string& b : bases) names += (names.empty() ? "" : ", ") + b;
    throw std::invalid_argument("refine_iterations " + std::to_string(refine_iterations) +
                                " fits a C-VAE's latent codes to the views, and no model given "
                                "has one (" +
                                names + "): give a C-VAE's model");
  }
  methods.push_back(std::make_unique<FusionMethod>(extent_m, resolution, truncation_m));
  return methods;
}

std::string distinctName(const std::string& name,
                         const std::vector<std::unique_ptr<EvaluatedMethod>>& methods) {
  for (const auto& other : methods)
    if (other->name() == name) return name + "_" + std::to_string(methods.size());
  return name;
}

std::vector<std::unique_ptr<EvaluatedMethod>> evaluatedMethods(
    const std::vector<PerceptionConfig>& configs, bool classical, double extent_m, int resolution) {
  std::vector<std::unique_ptr<EvaluatedMethod>> methods;
  for (PerceptionConfig c : configs) {
    c.zero_code_first = false;  // random codes, as the paper evaluates
    auto m = std::make_unique<NetworkMethod>(c);
    m->rename(distinctName(m->name(), methods));
    methods.push_back(std::move(m));
  }
  if (classical && !configs.empty()) {
    ClassicalConfig cc;
    cc.threads = configs.front().threads;
    cc.fit = configs.front().fit;
    methods.push_back(std::make_unique<ClassicalMethod>(cc, extent_m, resolution));
  }
  return methods;
}

}  // namespace simstack
