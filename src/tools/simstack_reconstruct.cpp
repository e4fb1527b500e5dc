// simstack_reconstruct: one depth file -> superquadrics, instance meshes, a labelled cloud,
// the predicted grids and pictures (ScenePerception on a file instead of a topic).
#include <CLI/CLI.hpp>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "cli_checks.h"
#include "depth_files.h"
#include "perception_options.h"
#include "simstack/io/image_io.h"
#include "simstack/io/scene_io.h"
#include "simstack/io/staged_output.h"
#include "simstack/model/cpu_allocator.h"
#include "simstack/offline/reconstruction/reconstruction_files.h"

using namespace simstack;
namespace fs = std::filesystem;

int main(int argc, char** argv) {
  std::vector<std::string> depth_paths, pose_paths;
  std::string intrinsics, mask_path, output;
  double depth_scale = 0.001;
  CLI::App app{
      "Reconstruct a pile from one depth image (or several posed ones): superquadrics (YAML), "
      "instance meshes (PLY), a labelled instance cloud (PCD), the predicted grids (HDF5) and PNG "
      "pictures."};
  app.add_option("--depth", depth_paths,
                 "16-bit PNG (units of --depth-scale), 32-bit float TIFF in metres, or a PCD: "
                 "organized, or unorganized and placed on the pixels of --intrinsics (the image of "
                 "the size they give, else the one they centre) or of the view file; repeat it for "
                 "more views of the scene, each with its "
                 "--table-pose (the outputs are drawn over the first)")
      ->required()
      ->check(CLI::ExistingFile);
  app.add_option("--intrinsics", intrinsics,
                 "fx,fy,cx,cy in pixels, optionally followed by the image's width,height; may be "
                 "left out when every --depth has its --table-pose view file, which holds them");
  const CLI::Option* scale_option =
      app.add_option("--depth-scale", depth_scale,
                     "metres per unit of a 16-bit PNG (default: the --table-pose view file's "
                     "depth_scale_m, else 0.001)")
          ->check(FinitePositive);
  app.add_option("--table-pose", pose_paths,
                 "YAML with T_table_camera (a view file of simstack_generate --views), one per "
                 "--depth in the same order; without it (one depth only) the table plane is "
                 "estimated from the depth (RANSAC)")
      ->check(CLI::ExistingFile);
  app.add_option("--mask", mask_path,
                 "8-bit PNG of the (first) depth's size: pixels where it is 0 are ignored (not "
                 "the workspace), also for the table plane")
      ->check(CLI::ExistingFile);
  app.add_option("--output", output, "output directory (created)")->required()->check(WritablePath);
  const PerceptionOptions perception(app);
  readIntegersInDecimal(app);
  CLI11_PARSE(app, argc, argv);
  keepFreedMemoryForReuse();  // the network runs in this process

  try {
    if (depth_paths.size() > 1 && pose_paths.size() != depth_paths.size())
      throw std::invalid_argument(std::to_string(depth_paths.size()) +
                                  " --depth files need as many " + "--table-pose files (given " +
                                  std::to_string(pose_paths.size()) +
                                  "): views after the first must be posed");
    if (pose_paths.size() > depth_paths.size())
      throw std::invalid_argument("more --table-pose files than --depth files");
    std::vector<DepthView> views;
    for (size_t i = 0; i < depth_paths.size(); ++i)
      views.push_back(readDepthFileView(
          depth_paths[i], scale_option->count() ? std::optional<double>(depth_scale) : std::nullopt,
          intrinsics, i < pose_paths.size() ? pose_paths[i] : "", i == 0 ? mask_path : ""));
    const DepthView& view = views.front();
    const std::string pose_path = pose_paths.empty() ? "" : pose_paths.front();
    const PerceptionConfig config = perception.config();
    StagedDirectory staged(output, "simstack_reconstruct");  // a bad --output fails here
    const ScenePerception pipeline(config);
    const SceneEstimate est = [&] {
      try {
        return pipeline.perceive(views);
      } catch (const std::exception& e) {  // what the depth holds: named by its file
        std::string files;
        for (const std::string& p : depth_paths) files += (files.empty() ? "" : ", ") + p;
        throw std::runtime_error("perceiving " + files + ": " + e.what());
      }
    }();
    const std::vector<std::string> files =
        writeReconstruction(staged.path(), view, est, labelMinHeight(config), views.size() == 1);
    staged.commit();  // replaces an earlier run's directory whole

    const StageTimings& t = est.timings;
    std::cout << "model " << config.model_path
              << (config.model_card_path.empty()
                      ? " (no card beside it: the config's samples and Hough setting)"
                      : " (card " + config.model_card_path + ")")
              << "\n";
    std::cout
        << views.size() << (views.size() == 1 ? " view" : " views") << "; table "
        << (est.table_estimated ? "estimated by RANSAC" : "from " + pose_path) << "\n"
        << est.instances().size() << " objects in a grid of " << est.tile_side_m << " m; "
        << est.tiles << (est.tiles == 1 ? " tile" : " tiles") << " perceived"
        << (est.tiles_cropped ? " (workspace.max_tiles reached: the pile is cut)" : "")
        << std::fixed << std::setprecision(1)
        << "; timings (ms, one frame with the network's first pass, slower than a node's next "
           "frames): table "
        << t.table_ms << ", tsdf " << t.tsdf_ms << ", network " << t.network_ms << ", instances "
        << t.instances_ms << ", mesh " << t.mesh_ms << ", fitting " << t.fitting_ms << ", total "
        << t.total_ms << "\nwrote " << (fs::path(output) / "").lexically_normal().string() << "{";
    for (size_t i = 0; i < files.size(); ++i) std::cout << (i ? ", " : "") << files[i];
    std::cout << "}\n";
    return 0;
  } catch (const std::exception& e) {
    std::cerr << "simstack_reconstruct: " << e.what() << "\n";
    return 1;
  }
}
