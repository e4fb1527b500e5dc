// simstack_rank_grasps: suction grasps on one object of a reconstructed scene, ranked by how
// little the rest of the pile moves when each pull is simulated (the grasp service without ROS).
#include <CLI/CLI.hpp>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <optional>

#include "cli_checks.h"
#include "perception_options.h"
#include "simstack/fitting/superquadric_fit.h"
#include "simstack/grasping/grasp_files.h"
#include "simstack/grasping/grasp_request.h"
#include "simstack/grasping/grasp_settings.h"
#include "simstack/io/scene_io.h"
#include "simstack/io/staged_output.h"

using namespace simstack;
namespace fs = std::filesystem;

namespace {

/// The depth points measured on the target: those labelled target_id + 1 in `cloud_path`, or
/// in the reconstruction's instances.pcd beside the scene file when none is given (none when
/// there is no such file: said). A cloud whose target points lie mostly away from the target's
/// shape is another scene's, or labelled otherwise: refused.
Points3 measuredTarget(const std::string& scene_path, std::string cloud_path, int target_id,
                       const SuperquadricShape& target) {
  if (cloud_path.empty()) {
    const fs::path beside = fs::path(scene_path).parent_path() / "instances.pcd";
    if (!fs::exists(beside)) {
      std::cout << "no measured cloud (no --measured, no " << beside.string()
                << "): seals judged on the superquadric alone\n";
      return {};
    }
    cloud_path = beside.string();
  }
  Points3 out = readLabelledPoints(cloud_path, static_cast<uint32_t>(target_id + 1));
  if (const std::string why = measuredOffTarget(out, target); !why.empty())
    throw std::invalid_argument("of the points labelled " + std::to_string(target_id + 1) + " in " +
                                cloud_path + ", " + why + " (object " + std::to_string(target_id) +
                                " in " + scene_path +
                                "): is it this scene's cloud, labelled id + 1?");
  std::cout << "seals judged on " << out.size() << " points of object " << target_id
            << " measured in " << cloud_path
            << (out.empty() ? " (none: seals judged on the superquadric alone)" : "") << "\n";
  return out;
}

/// The service's checks on the request: bounds, and a valid scene resting on the table (one far
/// below z = 0 of its frame is refused, one above it said).
PreparedGrasps prepare(const std::vector<SuperquadricShape>& scene, int target,
                       const GraspSettings& settings, double pregrasp_m,
                       const std::string& scene_path) {
  const GraspRankingConfig& config = settings.ranking;
  GraspRequest request;
  request.scenes = {scene};
  request.target = target;
  request.pull_distance_m = config.pull.pull_distance_m;
  request.pull_speed_mps = config.pull.pull_speed_mps;
  request.candidates = static_cast<uint32_t>(config.candidates.max_candidates);
  request.pregrasp_m = pregrasp_m;
  try {
    return prepareGrasps(request, config, settings.policy);
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(scene_path + ": " + e.what());
  }
}

/// The command line's grasp settings: the file's (config/grasps.yaml unless --config names
/// another), with the options given laid over them.
struct RankOptions {
  std::string config_path = packageFile("config/grasps.yaml");
  int candidates = 0, threads = 0, copies = 0;
  double pull_distance_m = 0, pull_speed_mps = 0, max_force_n = 0, cup_radius_m = 0;
  CLI::Option *candidates_opt = nullptr, *threads_opt = nullptr, *copies_opt = nullptr,
              *distance_opt = nullptr, *speed_opt = nullptr, *force_opt = nullptr,
              *cup_opt = nullptr;

  explicit RankOptions(CLI::App& app) {
    const PullConfig pull;  // a request's distance and speed when the options are not given
    pull_distance_m = pull.pull_distance_m;
    pull_speed_mps = pull.pull_speed_mps;
    app.add_option("--config", config_path,
                   "grasp settings (the grasp server's config/grasps.yaml: cup, seal, physics, "
                   "perturbed copies); the options below override it")
        ->capture_default_str()
        ->check(CLI::ExistingFile);
    candidates_opt =
        app.add_option("--candidates", candidates, "grasps to simulate (default: the file's)")
            ->check(CLI::Range(1, 1024));
    distance_opt = app.add_option("--pull-distance", pull_distance_m, "metres along the approach")
                       ->capture_default_str()
                       ->check(FinitePositive)
                       ->check(CLI::Range(1e-3, 1.0));
    speed_opt = app.add_option("--pull-speed", pull_speed_mps, "metres per second")
                    ->capture_default_str()
                    ->check(FinitePositive)
                    ->check(CLI::Range(1e-3, 2.0));
    force_opt = app.add_option("--max-force", max_force_n,
                               "newtons the seal holds (default: the file's max_force_n)")
                    ->check(FinitePositive)
                    ->check(CLI::Range(0.1, 1000.0));
    cup_opt =
        app.add_option("--cup-radius", cup_radius_m, "metres (default: the file's cup_radius_m)")
            ->check(FinitePositive)
            ->check(CLI::Range(0.002, 0.1));
    copies_opt = app.add_option("--perturbed-copies", copies,
                                "perturbed copies of the scene each grasp is also pulled in "
                                "(default: the file's perturbed_copies)")
                     ->check(CLI::Range(0, 64));
    threads_opt = app.add_option("--threads", threads,
                                 "threads simulating pulls, 0: all cores (default: the file's)")
                      ->check(CLI::Range(0, 1024));
  }

  /// The settings file's (checked as the server checks them), with the options given; the
  /// pull's distance and speed (a request's, in the service) are the options' or their
  /// defaults, and the bounds on a request (max_candidates_limit, max_pull_distance_m) this
  /// tool's option ranges.
  GraspSettings settings() const {
    GraspSettings s = loadGraspSettingsYaml(config_path, kGraspServerKeys);
    GraspRankingConfig& c = s.ranking;
    c.candidates.max_candidates = candidates_opt->count() ? candidates : s.policy.max_candidates;
    c.pull.pull_distance_m = pull_distance_m;
    c.pull.pull_speed_mps = pull_speed_mps;
    if (force_opt->count()) c.pull.max_force_n = max_force_n;
    if (cup_opt->count()) c.candidates.cup_radius_m = c.pull.cup_radius_m = cup_radius_m;
    if (copies_opt->count()) c.perturbation.copies = copies;
    if (threads_opt->count()) c.threads = threads;
    s.policy.max_candidates_limit = 1024;
    s.policy.max_pull_distance_m = 1.0;
    return s;
  }
};

}  // namespace

int main(int argc, char** argv) {
  std::string scene_path, output;
  int target_id = -1, rows = 10;
  CLI::App app{
      "Rank suction grasps on one object of a superquadrics.yaml (as simstack_reconstruct "
      "writes it): candidates on its visible surface where a cup seals, each pull simulated in "
      "Bullet, best first by the other objects' displacement; the grasp server's ranking and "
      "settings (config/grasps.yaml)."};
  app.add_option("--scene", scene_path, "superquadrics.yaml")->required()->check(CLI::ExistingFile);
  app.add_option("--target", target_id, "the target object's id in the scene file")->required();
  RankOptions options(app);
  app.add_option("--rows", rows, "grasps printed")
      ->capture_default_str()
      ->check(CLI::Range(1, 1024));
  std::string measured_path;
  app.add_option("--measured", measured_path,
                 "labelled cloud of the depth points measured on the objects (x y z label, label "
                 "id + 1: simstack_reconstruct's instances.pcd, taken from beside --scene when "
                 "this is not given); the target's judge its seals")
      ->check(CLI::ExistingFile);
  bool superquadric_seal = false;
  app.add_flag("--superquadric-seal", superquadric_seal,
               "judge seals on the superquadric alone, not on measured points");
  double pregrasp_m = 0.0;
  app.add_option("--pregrasp-distance", pregrasp_m,
                 "metres the pre-grasp pose in grasps.json stands back from the contact (0: the "
                 "settings' pregrasp_distance_m)")
      ->capture_default_str()
      ->check(FiniteNonNegative)
      ->check(CLI::Range(0.0, 1.0));
  app.add_option("--output", output, "directory for grasps.json and grasps.png (created)")
      ->check(WritablePath);
  readIntegersInDecimal(app);
  CLI11_PARSE(app, argc, argv);

  try {
    const GraspSettings settings = options.settings();
    std::vector<int> ids;
    std::optional<Vec3> camera;  // the one camera whose points were fitted, when the file says
    const std::vector<SuperquadricShape> scene = readSuperquadricsYaml(scene_path, &ids, &camera);
    const auto found = std::find(ids.begin(), ids.end(), target_id);
    if (found == ids.end()) {
      std::string known;
      for (int id : ids) known += (known.empty() ? "" : ", ") + std::to_string(id);
      throw std::invalid_argument("no object with id " + std::to_string(target_id) + " in " +
                                  scene_path + " (its ids: " + known + ")");
    }
    const int target = static_cast<int>(found - ids.begin());
    const PreparedGrasps prepared = prepare(scene, target, settings, pregrasp_m, scene_path);
    if (!prepared.notes.empty()) std::cout << prepared.notes << "\n";
    std::optional<StagedDirectory> staged;  // before the work: a bad --output fails at once
    if (!output.empty()) staged.emplace(output, "simstack_rank_grasps");
    const Points3 measured =
        superquadric_seal ? Points3()
                          : measuredTarget(scene_path, measured_path, target_id, scene[target]);
    const auto start = std::chrono::steady_clock::now();
    const GraspRanking ranking = rankGrasps(prepared.scenes, target, prepared.cameras,
                                            prepared.config, {}, measured, camera);
    const double seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    char took[32];
    std::snprintf(took, sizeof took, "%.2f", seconds);
    std::cout << "object " << target_id << ": " << ranking.candidates.visible << " of "
              << ranking.candidates.surface_samples << " surface samples seen, "
              << ranking.candidates.sealable << " sealable; " << ranking.grasps.size()
              << " grasps ranked (" << ranking.pulls << " pulls in " << took << " s)\n";
    if (!ranking.message.empty()) std::cout << ranking.message << "\n";
    std::cout << graspTable(ranking, rows);
    if (!output.empty()) {
      writeGraspJson((fs::path(staged->path()) / "grasps.json").string(), ranking, target_id,
                     prepared.pregrasp_m);
      writeGraspPicture((fs::path(staged->path()) / "grasps.png").string(), scene, ranking.grasps,
                        5);
      staged->commit();
      const std::string json = (fs::path(output) / "grasps.json").string();
      const std::string png = (fs::path(output) / "grasps.png").string();
      std::cout << "wrote " << json << " and " << png << " (the best 5 grasps)\n";
    }
  } catch (const std::exception& e) {
    std::cerr << "simstack_rank_grasps: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
