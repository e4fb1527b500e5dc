#include "simstack/grasping/grasp_ranking.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdlib>
#include <exception>
#include <limits>
#include <mutex>
#include <numeric>
#include <optional>
#include <random>
#include <set>
#include <stdexcept>
#include <system_error>
#include <thread>

namespace simstack {

std::string outcomeNote(const std::vector<RankedGrasp>& grasps) {
  if (grasps.empty()) return {};
  auto any = [&](auto pred) { return std::any_of(grasps.begin(), grasps.end(), pred); };
  if (!any([](const RankedGrasp& g) { return g.failed_share < 1.0; }))
    return "none of the " + std::to_string(grasps.size()) +
           " grasps held: every pull broke the seal in every hypothesis (the target too heavy "
           "for the cup, or pulled too fast)";
  std::string note;
  if (!any([](const RankedGrasp& g) { return g.failed_share == 0.0; }))
    note = "no grasp held in every hypothesis (each broke its seal in one at least)";
  if (!any([](const RankedGrasp& g) { return g.freed_share > 0.0; }))
    addNote(&note,
            "no grasp freed the target in any hypothesis (it stayed against another object)");
  else if (any([](const RankedGrasp& g) { return g.held(); }) &&
           !any([](const RankedGrasp& g) { return g.held() && g.freed(); }))
    // Whether the seal held is the first sort key: a grasp that held everywhere and freed the
    // target in none ranks before one that freed it in two of three and slipped in the third.
    addNote(&note,
            "no grasp both held and freed the target in every hypothesis: the first that held "
            "frees it in fewer (each grasp's freed_share says in how many)");
  return note;
}

namespace {

// Runs job(i) for i in [0, count) on `threads` threads. Each job writes only its own result,
// so the outcome does not depend on the thread count. The first exception is rethrown.
template <typename Job>
void parallelFor(int count, int threads, const Job& job) {
  std::atomic<int> next{0};
  std::exception_ptr error;
  std::mutex error_mutex;
  const auto work = [&] {
    for (int i = next++; i < count; i = next++) {
      try {
        job(i);
      } catch (...) {
        std::lock_guard<std::mutex> lock(error_mutex);
        if (!error) error = std::current_exception();
      }
    }
  };
  std::vector<std::thread> pool;
  pool.reserve(std::max(0, std::min(threads, count) - 1));  // no reallocation under running threads
  try {
    for (int t = 1; t < std::min(threads, count); ++t) pool.emplace_back(work);
  } catch (const std::system_error&) {
    // No thread to be had (a process or pids limit): those started and this one do the work.
  }
  work();
  for (auto& t : pool) t.join();
  if (error) std::rethrow_exception(error);
}

int threadCount(int requested) {
  const int cores = std::max(1u, std::thread::hardware_concurrency());
  if (requested < 0) throw std::invalid_argument("threads must be >= 0 (0: all cores)");
  return requested == 0 ? cores : std::min(requested, cores);
}

/// `copies`: the last outcomes are pulls in perturbed copies.
void summarise(RankedGrasp* g, int copies, const SuperquadricShape& target) {
  const double n = static_cast<double>(g->outcomes.size());
  if (copies > 0) {
    int held = 0;
    for (size_t k = g->outcomes.size() - copies; k < g->outcomes.size(); ++k)
      held += g->outcomes[k].cup_held ? 1 : 0;
    g->copies_held_share = static_cast<double>(held) / copies;
  }
  const Vec3 arm = target.centroid() - g->candidate.contact_table;
  g->com_offset_m =
      (arm - arm.dot(g->candidate.approach_table) * g->candidate.approach_table).norm();
  // The shares and the mean topples from whole counts: n times 1/n added up can miss 1 (six
  // sixths do) and depends on the order, while held(), freed() and the ranking compare them
  // exactly.
  int failed = 0, freed = 0, toppled = 0;
  for (const PullOutcome& o : g->outcomes) {
    g->mean_displacement_m += o.mean_displacement_m / n;
    g->worst_displacement_m = std::max(g->worst_displacement_m, o.mean_displacement_m);
    g->max_displacement_m = std::max(g->max_displacement_m, o.max_displacement_m);
    toppled += o.toppled;
    failed += o.failed() ? 1 : 0;
    freed += o.target_freed ? 1 : 0;
    g->peak_load = std::max(g->peak_load, o.peak_load);
  }
  if (n > 0) {
    g->failed_share = failed / n;
    g->freed_share = freed / n;
    g->mean_toppled = toppled / n;
  }
  g->score_m = 0.5 * (g->mean_displacement_m + g->worst_displacement_m);
}

std::string settlingNote(const std::vector<SceneDrift>& baseline,
                         const std::vector<int>& hypotheses) {
  // A large motion is what a robot must hear of: the neighbours' reactions are judged where
  // the objects came to rest, not where the camera saw them. (How much a scene still moves
  // after settling is its baseline.)
  double moved = 0.0;
  int worst = 0;
  for (size_t h = 0; h < baseline.size(); ++h)
    if (baseline[h].presettle_displacement_m > moved) {
      moved = baseline[h].presettle_displacement_m;
      worst = hypotheses[h];
    }
  if (!(moved > SceneDrift::kMovedWhileSettling_m)) return {};
  return "the scene's objects moved up to " + std::to_string(std::lround(moved * 1e3)) +
         " mm while settling before the pulls (hypothesis " + std::to_string(worst) +
         "; objects that overlap, float or stand in the table): the pulls start from where "
         "they came to rest";
}

}  // namespace

// Each candidate's seal tests read every point: a request's cloud of millions would hold the
// ranking for minutes before its first pull; every k-th point keeps the footprint covered.
const Points3& sealPoints(const Points3& measured, Points3* thinned, std::string* message) {
  if (measured.size() <= kMaxMeasuredPoints) return measured;
  const size_t stride = (measured.size() + kMaxMeasuredPoints - 1) / kMaxMeasuredPoints;
  for (size_t i = 0; i < measured.size(); i += stride) thinned->push_back(measured[i]);
  addNote(message, "seals judged on one in " + std::to_string(stride) + " of the " +
                       std::to_string(measured.size()) + " measured points");
  return *thinned;
}

void PerturbationConfig::validate() const {
  if (copies < 0 || copies > 64)
    throw std::invalid_argument("perturbed_copies must lie in [0, 64]");
  if (!(position_m >= 0.0 && position_m <= 0.1))
    throw std::invalid_argument("perturb_position_m must lie in [0, 0.1] m");
  if (!(rotation_deg >= 0.0 && rotation_deg <= 45.0))
    throw std::invalid_argument("perturb_rotation_deg must lie in [0, 45]");
  if (!(scale_share >= 0.0 && scale_share <= 0.5))
    throw std::invalid_argument("perturb_scale_share must lie in [0, 0.5]");
}

std::vector<std::vector<SuperquadricShape>> perturbedCopies(
    const std::vector<SuperquadricShape>& scene, const PerturbationConfig& config) {
  config.validate();
  std::mt19937_64 rng(config.seed * 0x9E3779B97F4A7C15ull + 17);
  std::normal_distribution<double> unit(0.0, 1.0);
  std::vector<std::vector<SuperquadricShape>> out;
  for (int c = 0; c < config.copies; ++c) {
    std::vector<SuperquadricShape> copy = scene;
    for (SuperquadricShape& sq : copy) {
      const double bottom = sceneBottom({sq});
      sq.T_table_object.translation() += config.position_m * Vec3(unit(rng), unit(rng), 0.0);
      const Vec3 axis = Vec3(unit(rng), unit(rng), unit(rng)).normalized();
      const double angle = config.rotation_deg * M_PI / 180.0 * unit(rng);
      sq.T_table_object.linear() =
          Eigen::AngleAxisd(angle, axis).toRotationMatrix() * sq.T_table_object.linear();
      for (int i = 0; i < 3; ++i)
        sq.scale_m[i] *= std::clamp(1.0 + config.scale_share * unit(rng), 0.5, 1.5);
      // No deeper into the table than it was: the simulation's table would throw it up.
      const double lowest = std::min(bottom, 0.0);
      const double now = sceneBottom({sq});
      if (now < lowest) sq.T_table_object.translation().z() += lowest - now;
    }
    out.push_back(std::move(copy));
  }
  return out;
}

std::optional<Vec3> carryCandidate(const SuctionCandidate& c, const SuperquadricShape& target,
                                   double tool_length_m) {
  // From outside the target's bounding sphere (a taller estimate of it must not start the
  // search inside), and at least the tool and 5 cm out.
  const Vec3 a = c.approach_table.normalized();
  const double radius = target.scale_m.norm();
  const double out =
      std::max(tool_length_m + 0.05, (target.centroid() - c.contact_table).dot(a) + radius + 1e-3);
  return enterSuperquadric(target, c.contact_table + out * a, -a, out + 2.0 * radius + 0.1);
}

PullOutcome executeGrasp(const PullSimulator& sim, const std::vector<SuperquadricShape>& scene,
                         int target, const SuctionCandidate& c, double tool_length_m) {
  const auto contact = carryCandidate(c, scene.at(target), tool_length_m);
  if (!contact) {
    PullOutcome miss;
    miss.cup_held = false;  // nothing to hold where this scene puts the target
    return miss;
  }
  return sim.pullPerceived(target, *contact, c.approach_table);
}

std::string checkIds(const std::vector<uint32_t>& ids) {
  std::set<uint32_t> seen;
  for (const uint32_t id : ids)
    if (!seen.insert(id).second)
      return "object id " + std::to_string(id) + " appears twice: ids must be unique";
  return {};
}

std::string checkScene(const std::vector<SuperquadricShape>& scene,
                       const std::vector<uint32_t>& ids) {
  // Each pull simulates every object: a scene of thousands would hold a request for hours.
  if (scene.size() > kMaxGraspSceneObjects)
    return std::to_string(scene.size()) + " objects: at most " +
           std::to_string(kMaxGraspSceneObjects) + " are simulated";
  if (ids.size() == scene.size())
    if (std::string why = checkIds(ids); !why.empty()) return why;
  for (size_t i = 0; i < scene.size(); ++i) {
    const SuperquadricShape& sq = scene[i];
    const std::string name =
        "object " + std::to_string(ids.size() == scene.size() ? ids[i] : i) + ": ";
    if (!sq.scale_m.allFinite() || (sq.scale_m.array() <= 0.0).any() ||
        (sq.scale_m.array() > 1.0).any())
      return name + "semi-axes must be finite and in (0, 1] m";
    if (!sq.exponents.allFinite() || (sq.exponents.array() < 1.0).any() ||
        (sq.exponents.array() > 200.0).any())
      return name + "exponents must be finite and in [1, 200]";
    if (!sq.T_table_object.matrix().allFinite()) return name + "pose is not finite";
    // Beyond a workcell's reach the physics and the ray casts lose their precision (Embree
    // refuses a ray from 1e30 m).
    const double from_origin = sq.T_table_object.translation().norm();
    if (from_origin > kMaxGraspSceneReachM)
      return name + "lies " + std::to_string(from_origin) + " m from the table's origin; at most " +
             std::to_string(static_cast<int>(kMaxGraspSceneReachM)) + " m is simulated";
    const Mat3 R = sq.T_table_object.linear();
    if (!(R.transpose() * R).isIdentity(1e-6) || !(std::abs(R.determinant() - 1.0) < 1e-6))
      return name + "orientation is not a rotation";
  }
  return {};
}

int matchObject(const SuperquadricShape& reference, const std::vector<SuperquadricShape>& scene,
                double match_distance_m) {
  const double gate = std::max(match_distance_m, reference.scale_m.maxCoeff());
  int best = -1;
  double best_d = gate;
  for (size_t i = 0; i < scene.size(); ++i) {
    const double d = (scene[i].centroid() - reference.centroid()).norm();
    if (d <= best_d) best = static_cast<int>(i), best_d = d;
  }
  return best;
}

void addNote(std::string* message, const std::string& note) {
  *message += (message->empty() ? "" : "; ") + note;
}

bool rankedBefore(const RankedGrasp& a, const RankedGrasp& b) {
  if (a.failed_share != b.failed_share) return a.failed_share < b.failed_share;
  if (a.freed_share != b.freed_share) return a.freed_share > b.freed_share;
  if (a.mean_toppled != b.mean_toppled) return a.mean_toppled < b.mean_toppled;
  // A seal the camera saw is a fact, one on a face it did not see a guess of the estimate.
  if (a.candidate.measured != b.candidate.measured) return a.candidate.measured;
  // A pull that lifts against gravity depends least on where the estimate puts the target's
  // neighbours and centre of mass (docs/experiments.md, "Grasp ranking").
  const double ua = std::round(a.candidate.approach_table.z() * 10.0),
               ub = std::round(b.candidate.approach_table.z() * 10.0);
  if (ua != ub) return ua > ub;
  const double da = std::round(a.score_m * 1e3), db = std::round(b.score_m * 1e3);
  if (da != db) return da < db;
  const double ca = std::round(a.com_offset_m * 1e3), cb = std::round(b.com_offset_m * 1e3);
  if (ca != cb) return ca < cb;
  return a.peak_load < b.peak_load;
}

GraspOutcome graspOutcome(const RankedGrasp& g) {
  if (!g.held()) return GraspOutcome::kFailed;
  return g.freed() ? GraspOutcome::kHeldAndFreed : GraspOutcome::kHeld;
}

Vec3 outcomeColour(GraspOutcome outcome) {
  return {outcome == GraspOutcome::kHeldAndFreed ? 0.0 : 1.0,
          outcome == GraspOutcome::kFailed ? 0.0 : 1.0, 0.0};
}

GraspRanking rankGrasps(const std::vector<std::vector<SuperquadricShape>>& hypotheses, int target,
                        const std::vector<Vec3>& camera_positions, const GraspRankingConfig& config,
                        const RankingProgress& progress, const Points3& measured_target,
                        const std::optional<Vec3>& measured_from) {
  if (hypotheses.empty()) throw std::invalid_argument("no scene to rank grasps in");
  for (size_t h = 0; h < hypotheses.size(); ++h)
    if (const std::string why = checkScene(hypotheses[h]); !why.empty())
      throw std::invalid_argument(
          (h == 0 ? std::string("the scene's ") : "hypothesis " + std::to_string(h) + "'s ") + why);
  if (target < 0 || target >= static_cast<int>(hypotheses[0].size()))
    throw std::invalid_argument("target " + std::to_string(target) + " is not an object of the " +
                                std::to_string(hypotheses[0].size()) + "-object scene");
  config.pull.validate();
  const auto finite = [](const Vec3& p) { return p.allFinite(); };
  for (size_t k = 0; k < camera_positions.size(); ++k)
    if (!finite(camera_positions[k]))
      throw std::invalid_argument("camera position " + std::to_string(k) + " is not finite");
  if (measured_from && !finite(*measured_from))
    throw std::invalid_argument("the measuring camera's position is not finite");
  if (const auto bad = std::find_if_not(measured_target.begin(), measured_target.end(), finite);
      bad != measured_target.end())
    throw std::invalid_argument("measured point " + std::to_string(bad - measured_target.begin()) +
                                " of " + std::to_string(measured_target.size()) + " is not finite");
  const int threads = threadCount(config.threads);
  GraspRanking out;
  Points3 thinned;
  const Points3& measured = sealPoints(measured_target, &thinned, &out.message);
  const auto& scene0 = hypotheses[0];
  out.candidates = suctionCandidates(
      scene0, target, camera_positions.empty() ? defaultCameraPositions(scene0) : camera_positions,
      config.candidates, measured, measured_from);
  if (out.candidates.seen_through > 0)
    addNote(&out.message, std::to_string(out.candidates.seen_through) +
                              " sealable places left out where the camera saw past the shape "
                              "(an opening the superquadric closes)");
  std::vector<int> targets;
  for (size_t h = 0; h < hypotheses.size(); ++h) {
    const int t =
        h == 0 ? target : matchObject(scene0[target], hypotheses[h], config.match_distance_m);
    if (t < 0) continue;
    out.hypotheses.push_back(static_cast<int>(h));
    targets.push_back(t);
  }
  if (out.hypotheses.size() < hypotheses.size())
    addNote(&out.message, std::to_string(hypotheses.size() - out.hypotheses.size()) +
                              " hypotheses without a match for the target were left out");
  if (out.candidates.candidates.empty()) {
    addNote(&out.message,
            "no sealable surface on the target: " + std::to_string(out.candidates.visible) +
                " of " + std::to_string(out.candidates.surface_samples) + " samples seen, " +
                std::to_string(out.candidates.reachable) + " reachable, none where a " +
                std::to_string(std::lround(config.candidates.cup_radius_m * 1000.0)) +
                " mm cup seals");
    return out;
  }
  // The perturbed copies of hypothesis 0, pulled in like further hypotheses.
  std::vector<std::vector<SuperquadricShape>> scenes;
  for (int h : out.hypotheses) scenes.push_back(hypotheses[h]);
  const size_t given = scenes.size();  // the caller's; the copies follow
  int next = static_cast<int>(hypotheses.size());
  const int copies = config.perturbation.copies;
  for (auto& copy : perturbedCopies(scene0, config.perturbation)) {
    out.hypotheses.push_back(next++);
    scenes.push_back(std::move(copy));
    targets.push_back(target);
  }
  const int H = static_cast<int>(scenes.size());
  std::vector<std::unique_ptr<PullSimulator>> sims(H);
  parallelFor(H, threads,
              [&](int k) { sims[k] = std::make_unique<PullSimulator>(scenes[k], config.pull); });
  for (const auto& s : sims) out.baseline.push_back(s->drift());
  // The copies' own shifts make them overlap: only the scenes the caller gave are said.
  if (const std::string note =
          settlingNote({out.baseline.begin(), out.baseline.begin() + given}, out.hypotheses);
      !note.empty())
    addNote(&out.message, note);
  const auto& cands = out.candidates.candidates;
  const int C = static_cast<int>(cands.size());
  std::vector<PullOutcome> outcomes(static_cast<size_t>(C) * H);
  // Each candidate is summarised once its every pull is done; progress reads the best of those.
  std::mutex progress_mutex;
  std::atomic<bool> stop{false};
  std::vector<int> pulls_of(C, 0);
  std::vector<std::optional<RankedGrasp>> ranked(C);
  const RankedGrasp* best = nullptr;
  int done = 0;
  parallelFor(C * H, threads, [&](int job) {
    if (stop) return;
    const int c = job / H, k = job % H;
    const auto& scene = scenes[k];
    outcomes[job] =
        k == 0
            ? sims[0]->pullPerceived(target, cands[c].contact_table, cands[c].approach_table)
            : executeGrasp(*sims[k], scene, targets[k], cands[c], config.candidates.tool_length_m);
    std::lock_guard<std::mutex> lock(progress_mutex);
    ++done;
    if (++pulls_of[c] == H) {
      RankedGrasp& g = ranked[c].emplace();
      g.candidate = cands[c];
      g.outcomes.assign(outcomes.begin() + c * H, outcomes.begin() + (c + 1) * H);
      summarise(&g, copies, scene0[target]);
      if (!best || rankedBefore(g, *best)) best = &g;
    }
    if (progress && !progress(done, C * H, best)) stop = true;
  });
  out.pulls = done;
  out.stopped = stop;
  for (std::optional<RankedGrasp>& g : ranked)
    if (g) out.grasps.push_back(std::move(*g));
  std::stable_sort(out.grasps.begin(), out.grasps.end(), rankedBefore);
  if (out.stopped)
    addNote(&out.message,
            "stopped after " + std::to_string(done) + " of " + std::to_string(C * H) + " pulls");
  if (const std::string note = outcomeNote(out.grasps); !note.empty()) addNote(&out.message, note);
  return out;
}

}  // namespace simstack
