#include "simstack/offline/eval/grasp_evaluation.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <map>
#include <numeric>
#include <random>
#include <sstream>
#include <stdexcept>

#include "simstack/offline/dataset/viewpoints.h"
#include "simstack/render/depth_renderer.h"
#include "simstack/seeds.h"

namespace simstack {
namespace {

std::vector<SuperquadricShape> trueShapes(const Scene& scene, int index) {
  std::vector<SuperquadricShape> out;
  for (const SceneObject& o : scene.objects) {
    if (o.shape->kind() != ObjectShape::Kind::kSuperquadric)
      throw std::invalid_argument(
          "scene " + std::to_string(index) +
          ": the grasp evaluation simulates pulls on superquadric piles only, not meshes");
    out.push_back(o.superquadricTable());
  }
  return out;
}

// The candidate a chooser picks from a ranking on an estimate (nullptr when there is none).
const SuctionCandidate* choose(const GraspRanking& r, const std::string& chooser,
                               std::mt19937_64& rng) {
  if (r.grasps.empty()) return nullptr;
  if (chooser == "ranked") return &r.grasps.front().candidate;
  if (chooser == "random")
    return &r.grasps[std::uniform_int_distribution<size_t>(0, r.grasps.size() - 1)(rng)].candidate;
  const auto top = std::max_element(
      r.grasps.begin(), r.grasps.end(), [](const RankedGrasp& a, const RankedGrasp& b) {
        return a.candidate.contact_table.z() < b.candidate.contact_table.z();
      });
  return &top->candidate;
}

// A grasp chosen on an estimate, executed in the true pile: carried onto the true target along
// its approach line; with `true_seal`, the cup's rim must seal on the true surface there (as a
// real cup's must), else nothing is held; then pulled.
PullOutcome executeOnTruth(const PullSimulator& sim, const std::vector<SuperquadricShape>& truth,
                           int target, const SuctionCandidate& c,
                           const GraspEvaluationOptions& options) {
  const CandidateConfig& k = options.ranking.candidates;
  if (!options.true_seal) return executeGrasp(sim, truth, target, c, k.tool_length_m);
  PullOutcome no_seal;
  no_seal.cup_held = false;
  const auto contact = carryCandidate(c, truth[target], k.tool_length_m);
  if (!contact || !(rimDeviation(truth[target], *contact, c.approach_table, k.cup_radius_m,
                                 k.rim_points, k.seal_tolerance_m) <= k.seal_tolerance_m))
    return no_seal;
  return sim.pullPerceived(target, *contact, c.approach_table);
}

// The ranking's candidate whose pull does best in the true pile, by the ranking's own order
// applied to the true outcomes: what a perfect ranking of these candidates would pick.
// Every trial is kept in `trials`.
const RankedGrasp* bestInTruth(const GraspRanking& r, const PullSimulator& truth_sim,
                               const std::vector<SuperquadricShape>& truth, int target,
                               const GraspEvaluationOptions& options, PullOutcome* outcome,
                               std::vector<CandidateTrial>* trials) {
  const RankedGrasp* best = nullptr;
  RankedGrasp best_true;
  for (const RankedGrasp& g : r.grasps) {
    RankedGrasp t = g;
    const PullOutcome o = executeOnTruth(truth_sim, truth, target, g.candidate, options);
    trials->push_back({g, o});
    t.outcomes = {o};
    t.failed_share = o.failed() ? 1.0 : 0.0;
    t.freed_share = o.target_freed ? 1.0 : 0.0;
    t.mean_toppled = o.toppled;
    t.score_m = o.mean_displacement_m;
    t.peak_load = o.peak_load;
    if (!best || rankedBefore(t, best_true)) best = &g, best_true = t, *outcome = o;
  }
  return best;
}

/// The random chooser's stream for one pick: from the seed, the scene, the target and the
/// method's name alone, so that a pick does not depend on the other methods or scenes of a run.
std::mt19937_64 pickStream(uint64_t seed, int scene, int target, const std::string& method) {
  uint64_t h = 1469598103934665603ull;  // FNV-1a of the name
  for (const char c : method) h = (h ^ static_cast<unsigned char>(c)) * 1099511628211ull;
  return std::mt19937_64(splitMix64(splitMix64(splitMix64(seed) ^ static_cast<uint64_t>(scene)) ^
                                    static_cast<uint64_t>(target)) ^
                         h);
}

// The picks of every chooser for one method's estimate of one target.
void pickOnEstimate(const std::vector<SuperquadricShape>& truth, const PullSimulator& truth_sim,
                    int scene, int target, const std::string& method,
                    const MethodEstimate& estimate, const GraspEvaluationOptions& options,
                    std::vector<PickResult>* out) {
  std::mt19937_64 rng = pickStream(options.seed, scene, target, method);
  const int k =
      matchObject(truth[target], estimate.superquadrics, options.ranking.match_distance_m);
  std::vector<std::vector<SuperquadricShape>> scenes{estimate.superquadrics};
  for (const auto& further : estimate.further_superquadrics)
    if (static_cast<int>(scenes.size()) < options.hypotheses) scenes.push_back(further);
  GraspRanking ranking;
  const Points3 none;
  const Points3& measured =
      k >= 0 && options.measured_seal && k < static_cast<int>(estimate.measured_surfaces.size())
          ? estimate.measured_surfaces[k]
          : none;
  if (k >= 0)
    ranking = rankGrasps(scenes, k, {}, options.ranking, {}, measured, estimate.measured_from);
  const EstimateError error =
      k >= 0 ? estimateError(estimate.superquadrics[k], truth[target]) : EstimateError();
  std::vector<std::string> choosers = {"ranked", "random", "top-most"};
  if (options.best_in_truth) choosers.emplace_back("best in truth");
  for (const std::string& chooser : choosers) {
    PickResult p;
    p.scene = scene, p.target = target, p.method = method, p.chooser = chooser;
    p.found = k >= 0;
    if (p.found) p.error = error;
    if (chooser == "best in truth") {
      p.grasped =
          bestInTruth(ranking, truth_sim, truth, target, options, &p.outcome, &p.trials) != nullptr;
      if (!p.grasped) p.outcome.cup_held = false;
      out->push_back(p);
      continue;
    }
    const SuctionCandidate* c = p.found ? choose(ranking, chooser, rng) : nullptr;
    p.grasped = c != nullptr;
    if (c)
      p.outcome = executeOnTruth(truth_sim, truth, target, *c, options);
    else
      p.outcome.cup_held = false;
    out->push_back(p);
  }
}

std::vector<PickResult> evaluateScene(const SceneRecord& rec, int index,
                                      const std::vector<EvaluatedMethod*>& methods,
                                      const GraspEvaluationOptions& options) {
  const std::vector<SuperquadricShape> truth = trueShapes(rec.scene, index);
  std::mt19937_64 rng(options.seed * 1000003ull + static_cast<uint64_t>(index));
  const PinholeCamera camera = scaledKinect(options.width, options.height);
  const Transform T_table_camera =
      sampleViewpoint(rec.scene.surfaceCentroid(), ViewpointRange(), rng);
  const DepthRenderer renderer(rec.scene);
  const RenderResult r = renderer.render(
      camera, T_table_camera,
      options.noise ? SensorNoiseConfig::preset(options.sensor, rng()) : SensorNoiseConfig());
  const DepthView view{r.depth, camera, T_table_camera};
  std::vector<MethodEstimate> estimates;
  for (EvaluatedMethod* m : methods)
    estimates.push_back(m->estimate(view, nullptr, rec.scene.surfaceCentroid().head<2>()));
  const PullSimulator truth_sim(truth, options.ranking.pull);
  std::vector<PickResult> out;
  for (int t = 0; t < static_cast<int>(truth.size()); ++t) {
    GraspRankingConfig exact = options.ranking;  // the truth is not uncertain
    exact.perturbation.copies = 0;
    const GraspRanking oracle = rankGrasps({truth}, t, {}, exact);
    PickResult p;
    p.scene = index, p.target = t, p.method = "truth", p.chooser = "ranked";
    p.grasped = !oracle.grasps.empty();
    p.outcome = p.grasped ? oracle.grasps.front().outcomes.front() : PullOutcome{};
    if (!p.grasped) p.outcome.cup_held = false;
    out.push_back(p);
    for (size_t m = 0; m < methods.size(); ++m)
      pickOnEstimate(truth, truth_sim, index, t, methods[m]->name(), estimates[m], options, &out);
  }
  return out;
}

double median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  return v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
}

// The rotations that pair the estimate's axes with the truth's as their lengths allow (signed
// permutation matrices of determinant 1; m * e_p[i] = +-e_i pairs the estimate's axis i with
// the truth's axis p[i]): the pairing by rank of length, and any other that only swaps true
// axes of lengths within 20 % of each other (a superquadric looks alike after such a turn).
std::vector<Mat3> axisTurns(const Vec3& estimate_scale, const Vec3& truth_scale) {
  const auto byLength = [](const Vec3& v) {  // the axes, shortest first
    std::array<int, 3> order{0, 1, 2};
    std::sort(order.begin(), order.end(), [&](int a, int b) { return v[a] < v[b]; });
    return order;
  };
  const std::array<int, 3> truth_order = byLength(truth_scale);
  const std::array<int, 3> estimate_order = byLength(estimate_scale);
  std::array<int, 3> estimate_rank{};
  for (int r = 0; r < 3; ++r) estimate_rank[estimate_order[r]] = r;
  std::vector<Mat3> out;
  std::array<int, 3> p{0, 1, 2};
  do {
    bool alike = true;
    for (int i = 0; i < 3; ++i) {
      const double paired = truth_scale[truth_order[estimate_rank[i]]];
      alike = alike && std::abs(truth_scale[p[i]] / paired - 1.0) <= 0.2;
    }
    if (!alike) continue;
    for (int signs = 0; signs < 8; ++signs) {
      Mat3 m = Mat3::Zero();
      for (int i = 0; i < 3; ++i) m(i, p[i]) = (signs >> i) & 1 ? -1.0 : 1.0;
      if (m.determinant() > 0) out.push_back(m);
    }
  } while (std::next_permutation(p.begin(), p.end()));
  return out;
}

}  // namespace

EstimateError estimateError(const SuperquadricShape& estimate, const SuperquadricShape& truth) {
  EstimateError e;
  e.centre_m = estimate.centroid() - truth.centroid();
  const Mat3 relative =
      truth.T_table_object.linear().transpose() * estimate.T_table_object.linear();
  double best = M_PI;
  for (const Mat3& t : axisTurns(estimate.scale_m, truth.scale_m))
    best = std::min(best, Eigen::AngleAxisd(relative * t).angle());
  e.rotation_deg = best * 180.0 / M_PI;
  Vec3 a = estimate.scale_m, b = truth.scale_m;
  std::sort(a.data(), a.data() + 3);
  std::sort(b.data(), b.data() + 3);
  e.scale_ratio = a.cwiseQuotient(b);
  return e;
}

nlohmann::json estimateErrorSummary(const std::vector<PickResult>& picks) {
  // Per method: |error| samples of the position across the table (per axis), the height, the
  // rotation and the semi-axes (per axis).
  std::map<std::string, std::array<std::vector<double>, 4>> samples;
  for (const PickResult& p : picks) {
    if (p.method == "truth" || p.chooser != "ranked" || !p.found) continue;
    auto& s = samples[p.method];
    s[0].push_back(std::abs(p.error.centre_m.x()));
    s[0].push_back(std::abs(p.error.centre_m.y()));
    s[1].push_back(std::abs(p.error.centre_m.z()));
    s[2].push_back(p.error.rotation_deg);
    for (int i = 0; i < 3; ++i) s[3].push_back(std::abs(p.error.scale_ratio[i] - 1.0));
  }
  const auto rms = [](const std::vector<double>& v) {
    double sum = 0;
    for (double x : v) sum += x * x;
    return std::sqrt(sum / v.size());
  };
  // The standard deviation a normal draw would have with this median |error|: robust to the
  // few estimates that are off by a whole object.
  const auto robust = [](const std::vector<double>& v) { return 1.4826 * median(v); };
  nlohmann::json out = nlohmann::json::array();
  for (const auto& [method, s] : samples)
    out.push_back({{"method", method},
                   {"targets", s[1].size()},
                   {"position_rms_m", rms(s[0])},
                   {"height_rms_m", rms(s[1])},
                   {"rotation_rms_deg", rms(s[2])},
                   {"scale_rms_share", rms(s[3])},
                   {"position_robust_sd_m", robust(s[0])},
                   {"height_robust_sd_m", robust(s[1])},
                   {"rotation_robust_sd_deg", robust(s[2])},
                   {"scale_robust_sd_share", robust(s[3])}});
  return out;
}

std::vector<PickResult> evaluateGrasps(const DatasetReader& reader,
                                       const std::vector<EvaluatedMethod*>& methods,
                                       const GraspEvaluationOptions& options,
                                       const std::function<void(int, int)>& progress) {
  const int n = options.scenes > 0 ? std::min(options.scenes, reader.size()) : reader.size();
  std::vector<PickResult> out;
  for (int i = 0; i < n; ++i) {
    const std::vector<PickResult> picks = evaluateScene(reader.readScene(i), i, methods, options);
    out.insert(out.end(), picks.begin(), picks.end());
    if (progress) progress(i + 1, n);
  }
  return out;
}

/// A chooser's freed share as a fraction of the oracle's on the same targets, with a 95 %
/// bootstrap interval over the targets (resampled in pairs, 2000 times, a fixed seed).
struct OracleFraction {
  double ratio = 0.0, low = 0.0, high = 0.0;
};
OracleFraction freedOfOracle(const std::vector<std::pair<double, double>>& freed_and_oracle) {
  OracleFraction out;
  const auto ratio = [](const std::vector<std::pair<double, double>>& v) {
    double a = 0, b = 0;
    for (const auto& [x, y] : v) a += x, b += y;
    return b > 0 ? a / b : NAN;  // undefined where the oracle freed nothing
  };
  if (freed_and_oracle.empty()) return out;
  out.ratio = ratio(freed_and_oracle);
  std::mt19937_64 rng(1);
  std::uniform_int_distribution<size_t> pick(0, freed_and_oracle.size() - 1);
  constexpr int kResamples = 2000;
  std::vector<double> boot;
  std::vector<std::pair<double, double>> sample(freed_and_oracle.size());
  for (int b = 0; b < kResamples; ++b) {
    for (auto& s : sample) s = freed_and_oracle[pick(rng)];
    if (const double r = ratio(sample); std::isfinite(r)) boot.push_back(r);
  }
  // Resamples without an oracle success have no ratio: left out, and with more than 2.5 % of
  // them (too few targets the oracle frees) the interval's low end is not known: none given.
  if (boot.size() < 0.975 * kResamples) {
    out.low = out.high = NAN;
    return out;
  }
  std::sort(boot.begin(), boot.end());
  out.low = boot[static_cast<size_t>(0.025 * boot.size())];
  out.high = boot[static_cast<size_t>(0.975 * boot.size()) - 1];
  return out;
}

nlohmann::json graspSummary(const std::vector<PickResult>& picks) {
  // The oracle's pick of each target: what the others are measured against.
  std::map<std::pair<int, int>, const PickResult*> oracle;
  for (const PickResult& p : picks)
    if (p.method == "truth") oracle[{p.scene, p.target}] = &p;
  std::vector<std::pair<std::string, std::string>> keys;
  for (const PickResult& p : picks)
    if (std::find(keys.begin(), keys.end(), std::make_pair(p.method, p.chooser)) == keys.end())
      keys.emplace_back(p.method, p.chooser);
  nlohmann::json out = nlohmann::json::array();
  for (const auto& [method, chooser] : keys) {
    // A pick whose estimate had no match for the target, or no sealable point on it, was never
    // pulled: it frees nothing, and the pulls' own figures (seal, displacement, toppling) are
    // taken over the picks that were pulled, so that missing a target does not look gentle.
    std::vector<double> d, d_freed;
    std::vector<std::pair<double, double>> paired;  // (freed, the oracle freed) per target
    double toppled = 0, freed = 0, broke = 0, found = 0, pulled = 0, n = 0;
    // Seals broken on the targets both this method and the oracle pulled: the oracle's share
    // over all its pulls would set this method's breaks against targets it never tried.
    double both_broke = 0, both_oracle_broke = 0;
    for (const PickResult& p : picks) {
      if (p.method != method || p.chooser != chooser) continue;
      ++n;
      const auto o = oracle.find({p.scene, p.target});
      if (o != oracle.end())
        paired.emplace_back(p.outcome.target_freed, o->second->outcome.target_freed);
      found += p.found;
      freed += p.outcome.target_freed;
      if (!p.found || !p.grasped) continue;
      ++pulled;
      d.push_back(1e3 * p.outcome.mean_displacement_m);
      if (p.outcome.target_freed) d_freed.push_back(d.back());
      toppled += p.outcome.toppled > 0, broke += p.outcome.failed();
      if (o != oracle.end() && o->second->grasped)
        both_broke += p.outcome.failed(), both_oracle_broke += o->second->outcome.failed();
    }
    // A figure over nothing (no pull, an oracle that freed or broke nothing) is null, not 0.
    const nlohmann::json undefined;
    const auto share = [&](double a, double b) -> nlohmann::json {
      return b > 0 ? nlohmann::json(a / b) : undefined;
    };
    const auto mean = [&](const std::vector<double>& v) -> nlohmann::json {
      return v.empty() ? undefined
                       : nlohmann::json(std::accumulate(v.begin(), v.end(), 0.0) / v.size());
    };
    double oracle_freed = 0;
    for (const auto& [x, y] : paired) oracle_freed += y;
    const OracleFraction of_oracle = freedOfOracle(paired);
    const bool against_oracle = oracle_freed > 0;
    out.push_back(
        {{"method", method},
         {"chooser", chooser},
         {"picks", static_cast<long>(n)},
         {"pulled_share", share(pulled, n)},
         {"freed_share", share(freed, n)},
         {"seal_broke_share", share(broke, pulled)},
         {"mean_displacement_mm", mean(d)},
         {"median_displacement_mm", d.empty() ? undefined : nlohmann::json(median(d))},
         {"freed_mean_displacement_mm", mean(d_freed)},
         {"toppled_share", share(toppled, pulled)},
         {"target_found_share", share(found, n)},
         {"freed_of_oracle", against_oracle ? nlohmann::json(of_oracle.ratio) : undefined},
         {"freed_of_oracle_ci95", against_oracle && std::isfinite(of_oracle.low)
                                      ? nlohmann::json({of_oracle.low, of_oracle.high})
                                      : undefined},
         {"seal_broke_of_oracle", share(both_broke, both_oracle_broke)}});
  }
  return out;
}

std::string graspSummaryTable(const nlohmann::json& summary) {
  std::ostringstream out;
  out << "| scene from | grasp chosen by | picks | pulled | target freed | of the oracle's (95 % "
         "CI) | of the pulls: seal broke | of the oracle's | others moved, mean (mm) | median "
         "(mm) | mean when freed (mm) | toppled something |\n"
         "|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  // "-" where a figure is over nothing (null in the JSON).
  const auto cell = [](const nlohmann::json& v, double scale, const char* format) {
    if (v.is_null()) return std::string("-");
    char text[64];
    std::snprintf(text, sizeof text, format, scale * v.get<double>());
    return std::string(text);
  };
  for (const auto& r : summary) {
    const auto& ci = r["freed_of_oracle_ci95"];
    out << "| " << r["method"].get<std::string>() << " | " << r["chooser"].get<std::string>()
        << " | " << static_cast<int>(r["picks"].get<double>()) << " | "
        << cell(r["pulled_share"], 100, "%.0f %%") << " | "
        << cell(r["freed_share"], 100, "%.0f %%") << " | "
        << cell(r["freed_of_oracle"], 100, "%.0f %%")
        << (ci.is_null() ? std::string()
                         : " (" + cell(ci[0], 100, "%.0f") + "-" + cell(ci[1], 100, "%.0f") + ")")
        << " | " << cell(r["seal_broke_share"], 100, "%.0f %%") << " | "
        << cell(r["seal_broke_of_oracle"], 1, "%.2fx") << " | "
        << cell(r["mean_displacement_mm"], 1, "%.1f") << " | "
        << cell(r["median_displacement_mm"], 1, "%.1f") << " | "
        << cell(r["freed_mean_displacement_mm"], 1, "%.1f") << " | "
        << cell(r["toppled_share"], 100, "%.0f %%") << " |\n";
  }
  return out.str();
}

}  // namespace simstack
