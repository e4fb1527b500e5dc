// simstack_reconstruct: one depth file -> superquadrics, instance meshes, a labelled cloud,
// the predicted grids and pictures (ScenePerception on a file instead of a topic).
#include <CLI/CLI.hpp>

#include <filesystem>
#include <fstream>
#include <iostream>
#include <sstream>

#include "simstack/io/image_io.h"
#include "simstack/io/scene_io.h"
#include "simstack/mesh/marching_cubes.h"
#include "simstack/model/cpu_allocator.h"
#include "simstack/pipeline/scene_perception.h"
#include "simstack/render/depth_renderer.h"
#include "simstack/scene/scene.h"

using namespace simstack;
namespace fs = std::filesystem;

namespace {

std::string defaultModel() {
  for (const char* dir : {SIMSTACK_SOURCE_DIR "/models", SIMSTACK_SHARE_DIR "/models"}) {
    const fs::path p = fs::path(dir) / "simstack_r32.pt";
    if (fs::exists(p)) return p.string();
  }
  return SIMSTACK_SOURCE_DIR "/models/simstack_r32.pt";
}

PinholeCamera parseIntrinsics(const std::string& text, int width, int height) {
  std::stringstream ss(text);
  std::vector<double> v;
  std::string item;
  while (std::getline(ss, item, ',')) {
    try {
      size_t used = 0;
      v.push_back(std::stod(item, &used));
      if (used != item.size()) throw std::invalid_argument(item);
    } catch (const std::exception&) {
      throw std::invalid_argument("--intrinsics: '" + item + "' is not a number");
    }
  }
  if (v.size() != 4) throw std::invalid_argument("--intrinsics needs fx,fy,cx,cy (4 numbers)");
  PinholeCamera c;
  c.width = width;
  c.height = height;
  c.fx = v[0];
  c.fy = v[1];
  c.cx = v[2];
  c.cy = v[3];
  c.validate();
  return c;
}

/// Renders superquadrics from a camera and writes the shaded picture.
void renderShapes(const std::string& path, const std::vector<Superquadric>& shapes,
                  const PinholeCamera& camera, const Transform& T_table_camera) {
  const Scene scene = Scene::fromSuperquadrics(shapes);
  RenderConfig rc;
  rc.table_half_size_m = 5.0;  // the table origin may be far from the pile when estimated
  const DepthRenderer renderer(scene, rc);
  const RenderResult r = renderer.render(camera, T_table_camera, SensorNoiseConfig(), true);
  writeShadedPicture(path, r.instances, r.normals_table, T_table_camera);
}

}  // namespace

int main(int argc, char** argv) {
  std::string depth_path, intrinsics, pose_path, output, model = defaultModel(), config_path;
  double depth_scale = 0.001;
  int samples = 3, threads = 2;
  uint64_t seed = 0;
  bool no_joint = false;
  CLI::App app{
      "Reconstruct a pile from one depth image: superquadrics (YAML), instance meshes (PLY), a "
      "labelled instance cloud (PCD), the predicted grids (HDF5) and PNG pictures."};
  app.add_option("--depth", depth_path,
                 "16-bit PNG (units of --depth-scale), 32-bit float TIFF in metres, or an "
                 "organized PCD")
      ->required()
      ->check(CLI::ExistingFile);
  app.add_option("--intrinsics", intrinsics, "fx,fy,cx,cy in pixels")->required();
  app.add_option("--depth-scale", depth_scale, "metres per unit of a 16-bit PNG")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  app.add_option("--table-pose", pose_path,
                 "YAML with T_table_camera (a view file of simstack_generate --views); without "
                 "it the table plane is estimated from the depth (RANSAC)")
      ->check(CLI::ExistingFile);
  app.add_option("--output", output, "output directory (created)")->required();
  app.add_option("--config", config_path,
                 "perception parameters (config/perception.yaml); the options below override it")
      ->check(CLI::ExistingFile);
  app.add_option("--model", model, "trained model")->capture_default_str()->check(CLI::ExistingFile);
  app.add_option("--samples", samples, "latent samples S")->capture_default_str()->check(CLI::PositiveNumber);
  app.add_option("--seed", seed, "latent code seed")->capture_default_str();
  app.add_option("--threads", threads, "threads")->capture_default_str()->check(CLI::PositiveNumber);
  app.add_flag("--no-joint", no_joint, "skip the joint refinement (eqs. 7-9)");
  CLI11_PARSE(app, argc, argv);
  keepFreedMemoryForReuse();  // the network runs in this process

  try {
    DepthView view;
    const std::string ext = fs::path(depth_path).extension().string();
    view.depth = ext == ".pcd" ? readDepthPcd(depth_path) : readDepthImage(depth_path, depth_scale);
    view.camera = parseIntrinsics(intrinsics, view.depth.width, view.depth.height);
    if (!pose_path.empty()) view.T_table_camera = readViewYaml(pose_path).T_table_camera;

    PerceptionConfig config;
    if (!config_path.empty()) {
      config = loadPerceptionYaml(config_path, SIMSTACK_SOURCE_DIR);
      if (app.count("--model") || config.model_path.empty()) config.model_path = model;
    } else {
      config.model_path = model;
    }
    if (!config_path.empty() && !std::filesystem::exists(config.model_path))
      throw std::runtime_error(config_path + ": model " + config.model_path + " does not exist");
    if (config_path.empty() || app.count("--samples")) config.samples = samples;
    if (config_path.empty() || app.count("--seed")) config.seed = seed;
    if (config_path.empty() || app.count("--threads")) config.threads = threads;
    if (no_joint) config.joint_refinement = false;
    const ScenePerception perception(config);
    const SceneEstimate est = perception.perceive(view);

    std::error_code ec;
    fs::create_directories(output, ec);
    if (ec) throw std::runtime_error("cannot create " + output + ": " + ec.message());
    const fs::path out(output);
    const SceneHypothesis& h = est.hypotheses.front();
    std::vector<Superquadric> shapes;
    for (size_t k = 0; k < h.instances.size(); ++k) {
      shapes.push_back(h.instances[k].superquadric);
      writeMeshPly((out / ("instance_" + std::to_string(k) + ".ply")).string(), h.instances[k].mesh);
    }
    writeSuperquadricsYaml((out / "superquadrics.yaml").string(), shapes);
    writeMeshPly((out / "surface.ply").string(),
                 h.surface.empty() ? extractSurface(h.tsdf_m) : h.surface);

    // Visible points labelled by instance (0 = table or unassigned, k + 1 = instance k).
    const Image<int> pixel_labels = pixelInstances(view, est, 0, config.min_pile_height_m);
    Points3 pts;
    std::vector<int> labels;
    const GridSpec& g = est.grid;
    for (int v = 0; v < view.depth.height; ++v)
      for (int u = 0; u < view.depth.width; ++u) {
        const float d = view.depth.at(u, v);
        if (!validDepth(d)) continue;
        pts.push_back(est.T_table_camera * view.camera.backproject(u, v, d));
        labels.push_back(pixel_labels.at(u, v) + 1);
      }
    writeLabelledCloudPcd((out / "instances.pcd").string(), pts, labels);

    PredictionGrids grids;
    grids.grid = est.grid;
    grids.T_table_camera = est.T_table_camera;
    grids.tsdf_m = h.tsdf_m;
    grids.occupancy_probability = est.occupancy_probability;
    grids.partial_tsdf_m = est.partial_tsdf_m;
    grids.partial_weight = est.partial_weight;
    grids.labels = h.labels;
    writePredictionH5((out / "grids.h5").string(), grids);

    // Pictures: input depth, visible instances, superquadrics from the input view and from a
    // second view (rotated 90 degrees about the pile's vertical axis).
    writeDepthPicture((out / "depth.png").string(), view.depth);
    InstanceImage mask(view.depth.width, view.depth.height, kNoSurface);
    Image<Vec3f> normals(view.depth.width, view.depth.height, Vec3f(0, 0, 1));
    for (size_t i = 0, k = 0; i < static_cast<size_t>(view.depth.width) * view.depth.height; ++i)
      if (validDepth(view.depth.pixels[i])) mask.pixels[i] = static_cast<uint8_t>(std::min(labels[k++], 254));
    writeShadedPicture((out / "instances.png").string(), mask, normals, est.T_table_camera);
    renderShapes((out / "superquadrics_input_view.png").string(), shapes, view.camera,
                 est.T_table_camera);
    const Vec3 centre(g.origin_table.x() + 0.5 * g.extent_m(), g.origin_table.y() + 0.5 * g.extent_m(), 0.0);
    Transform turn = Transform::Identity();
    turn.translation() = centre;
    turn.rotate(Eigen::AngleAxisd(M_PI / 2, Vec3::UnitZ()));
    turn.translate(-centre);
    renderShapes((out / "superquadrics_second_view.png").string(), shapes, view.camera,
                 turn * est.T_table_camera);

    const StageTimings& t = est.timings;
    std::cout << "table " << (est.table_estimated ? "estimated by RANSAC" : "from " + pose_path)
              << "\n"
              << h.instances.size() << " objects; timings (ms): table " << t.table_ms << ", tsdf "
              << t.tsdf_ms << ", network " << t.network_ms << ", instances " << t.instances_ms
              << ", mesh " << t.mesh_ms << ", fitting " << t.fitting_ms << ", total " << t.total_ms
              << "\nwrote " << out.string()
              << "/{superquadrics.yaml, instance_*.ply, surface.ply, instances.pcd, grids.h5, "
                 "depth.png, instances.png, superquadrics_input_view.png, "
                 "superquadrics_second_view.png}\n";
    return 0;
  } catch (const std::exception& e) {
    std::cerr << "simstack_reconstruct: " << e.what() << "\n";
    return 1;
  }
}
