#include "simstack/offline/tuning/hough_tuning.h"

#include <omp.h>

#include <cmath>
#include <exception>
#include <iomanip>
#include <random>
#include <sstream>
#include <stdexcept>

#include "simstack/instances/instance_finder.h"
#include "simstack/offline/dataset/ground_truth.h"
#include "simstack/offline/dataset/viewpoints.h"
#include "simstack/offline/eval/segmentation.h"
#include "simstack/pipeline/scene_perception.h"
#include "simstack/render/depth_renderer.h"

namespace simstack {
namespace {

bool sameSetting(const HoughConfig& a, const HoughConfig& b) {
  return a.refinement == b.refinement && a.min_traversals == b.min_traversals &&
         a.gamma == b.gamma && a.bandwidth_m == b.bandwidth_m &&
         a.min_instance_voxels == b.min_instance_voxels && a.min_vote_norm == b.min_vote_norm &&
         a.outside_tolerance_vox == b.outside_tolerance_vox;
}

TuningView tuningView(const ScenePerception& perception, const InstanceFinder& finder,
                      const SceneRecord& rec, const DepthView& view, double truncation_m) {
  SceneEstimate est = perception.perceive(view);
  const GroundTruthGrids gt = computeGroundTruth(rec.scene, est.grid, truncation_m);
  TuningView g;
  g.tsdf_m = std::move(est.hypotheses[0].tsdf_m);
  g.votes = std::move(est.hypotheses[0].votes);
  g.truth.resize(gt.labels.data.size());
  for (size_t i = 0; i < g.truth.size(); ++i) g.truth[i] = static_cast<int>(gt.labels.data[i]) - 1;
  g.objects = static_cast<int>(rec.scene.objects.size());
  g.segments = finder.segmentView(view.depth, view.camera, *view.T_table_camera,
                                  perception.config().min_pile_height_m, &est.grid);
  return g;
}

}  // namespace

std::vector<TuningView> tuningViews(const DatasetReader& reader, const PerceptionConfig& config,
                                    int scenes, int views_per_scene, uint64_t seed, bool noise,
                                    const std::function<void(int, int)>& progress) {
  PerceptionConfig pc = config;
  pc.samples = 1;
  pc.zero_code_first = true;
  pc.decompose_samples = 0;
  // A card's setting is the model's own grid's (GridConfig scales it to another side).
  pc.grid = GridConfig();
  const ScenePerception perception(pc);
  const InstanceFinder finder(pc.hough, pc.segments);
  const int n = scenes > 0 ? std::min(scenes, reader.size()) : reader.size();
  const PinholeCamera camera = scaledKinect(640, 480);
  std::vector<TuningView> views;
  for (int k = 0; k < n; ++k) {
    const SceneRecord rec = reader.read(k);
    const DepthRenderer renderer(rec.scene);
    std::mt19937_64 rng(seed * 1000003ull + static_cast<uint64_t>(k));
    for (int v = 0; v < views_per_scene; ++v) {
      const Transform T = sampleViewpoint(rec.scene.surfaceCentroid(), ViewpointRange(), rng);
      const uint64_t noise_seed = rng();
      const RenderResult r = renderer.render(
          camera, T, noise ? SensorNoiseConfig::kinect(noise_seed) : SensorNoiseConfig());
      views.push_back(tuningView(perception, finder, rec, DepthView{r.depth, camera, T},
                                 reader.info().truncation_m));
    }
    if (progress) progress(k + 1, n);
  }
  return views;
}

std::vector<HoughConfig> houghCandidates(const HoughConfig& current, const HoughSweep& s) {
  HoughConfig first = current;
  first.threads = 1;
  std::vector<HoughConfig> out = {first};
  for (int ref : s.refinements)
    for (int mu : s.traversals)
      for (double bw : s.bandwidths)
        for (int mv : s.min_voxels)
          for (double norm : s.min_norms) {
            HoughConfig h = first;
            h.refinement = ref;
            h.min_traversals = mu;
            h.bandwidth_m = bw;
            h.min_instance_voxels = mv;
            h.min_vote_norm = norm;
            if (!sameSetting(h, first)) out.push_back(h);
          }
  return out;
}

HoughScore scoreHoughSetting(const std::vector<TuningView>& views, const HoughConfig& hough,
                             const SurfaceSegmentConfig& segments, const CrowdedConfig& crowded) {
  const InstanceFinder finder(hough, segments, crowded);
  HoughScore s;
  s.hough = hough;
  for (const TuningView& v : views) {
    InstanceSegmentation seg;
    try {
      seg = finder.find(v.tsdf_m, v.votes, v.segments ? &*v.segments : nullptr);
    } catch (const TooManyHoughCentres&) {  // a radius too small: counted as the over-count it is
      s.over += 1;
      s.abs_error += static_cast<double>(kMaxHoughCentres);
      continue;
    }
    const int error = seg.size() - v.objects;
    s.exact += error == 0;
    s.under += error < 0;
    s.over += error > 0;
    s.abs_error += std::abs(error);
    s.agreement += segmentationAgreement(v.truth, seg.labels.data).agreement;
  }
  const double n = static_cast<double>(views.size());
  s.exact /= n;
  s.under /= n;
  s.over /= n;
  s.abs_error /= n;
  s.agreement /= n;
  return s;
}

std::vector<HoughScore> scoreHoughSettings(const std::vector<TuningView>& views,
                                           const std::vector<HoughConfig>& candidates,
                                           const SurfaceSegmentConfig& segments,
                                           const CrowdedConfig& crowded, int threads,
                                           const std::function<void(long, long)>& progress) {
  if (views.empty()) throw std::runtime_error("no validation view to score the settings on");
  std::vector<HoughScore> scores(candidates.size());
  std::exception_ptr failure;  // an exception must not leave the parallel loop
  long done = 0;
  const long n = static_cast<long>(candidates.size());
#pragma omp parallel for schedule(dynamic) num_threads(threads)
  for (long i = 0; i < n; ++i) {
    try {
      scores[i] = scoreHoughSetting(views, candidates[i], segments, crowded);
    } catch (...) {
#pragma omp critical
      if (!failure) failure = std::current_exception();
    }
#pragma omp critical
    if (progress) progress(++done, n);
  }
  if (failure) std::rethrow_exception(failure);
  return scores;
}

bool betterHoughScore(const HoughScore& a, const HoughScore& b) {
  if (a.exact != b.exact) return a.exact > b.exact;
  return a.agreement > b.agreement;
}

std::string houghScoreHeader() {
  return "| refinement | mu | bandwidth (m) | min voxels | min vote norm | count exact | under | "
         "over | mean abs error | voxel agreement |\n|---|---|---|---|---|---|---|---|---|---|";
}

std::string houghScoreRow(const HoughScore& s) {
  std::ostringstream o;
  o << "| " << s.hough.refinement << " | " << s.hough.min_traversals << " | " << std::fixed
    << std::setprecision(3) << s.hough.bandwidth_m << " | " << s.hough.min_instance_voxels << " | "
    << std::setprecision(1) << s.hough.min_vote_norm << " | " << 100 * s.exact << " % | "
    << 100 * s.under << " % | " << 100 * s.over << " % | " << std::setprecision(2) << s.abs_error
    << " | " << std::setprecision(3) << s.agreement << " |";
  return o.str();
}

}  // namespace simstack
