#include "simstack/offline/reconstruction/reconstruction_files.h"

#include <algorithm>
#include <filesystem>

#include "simstack/io/image_io.h"
#include "simstack/io/scene_io.h"
#include "simstack/mesh/marching_cubes.h"
#include "simstack/render/depth_renderer.h"
#include "simstack/scene/scene.h"

namespace simstack {
namespace {

/// Renders superquadrics from a camera and writes the shaded picture.
void renderShapes(const std::string& path, const std::vector<SuperquadricShape>& shapes,
                  const PinholeCamera& camera, const Transform& T_table_camera) {
  const Scene scene = Scene::fromSuperquadrics(shapes);
  RenderConfig rc;
  rc.table_half_size_m = 5.0;  // the table origin may be far from the pile when estimated
  const DepthRenderer renderer(scene, rc);
  const RenderResult r = renderer.render(camera, T_table_camera, SensorNoiseConfig(), true);
  writeShadedPicture(path, r.instances, r.normals_table, T_table_camera);
}

/// The visible points (table frame) with their instance labels, and the pictures of them.
void writeVisibleInstances(const std::filesystem::path& out, const DepthView& view,
                           const SceneEstimate& est, double min_height_m) {
  const Image<int> pixel_labels = pixelInstances(view, est, 0, min_height_m);
  Points3 pts;
  std::vector<int> labels;
  InstanceImage mask(view.depth.width, view.depth.height, kNoSurface);
  for (int v = 0; v < view.depth.height; ++v)
    for (int u = 0; u < view.depth.width; ++u) {
      const float d = view.depth.at(u, v);
      if (!validDepth(d)) continue;
      pts.push_back(est.T_table_camera * view.camera.backproject(u, v, d));
      labels.push_back(pixel_labels.at(u, v) + 1);
      mask.at(u, v) = static_cast<uint8_t>(std::min(labels.back(), 254));
    }
  writeLabelledCloudPcd((out / "instances.pcd").string(), pts, labels);
  writeLabelsPng((out / "labels.png").string(), pixel_labels);
  writeDepthPicture((out / "depth.png").string(), view.depth);
  const Image<Vec3f> normals(view.depth.width, view.depth.height, Vec3f(0, 0, 1));
  writeShadedPicture((out / "instances.png").string(), mask, normals, est.T_table_camera);
}

void writeGrids(const std::filesystem::path& out, const SceneEstimate& est) {
  const SceneHypothesis& h = est.hypotheses.front();
  PredictionGrids grids;
  grids.grid = est.grid;
  grids.T_table_camera = est.T_table_camera;
  grids.tsdf_m = h.tsdf_m;
  grids.occupancy_probability = est.occupancy_probability;
  grids.partial_tsdf_m = est.partial_tsdf_m;
  grids.partial_weight = est.partial_weight;
  grids.labels = h.labels;
  writePredictionH5((out / "grids.h5").string(), grids);
}

}  // namespace

std::vector<std::string> writeReconstruction(const std::string& dir, const DepthView& view,
                                             const SceneEstimate& est, double min_height_m,
                                             bool one_view) {
  const std::filesystem::path out(dir);
  const SceneHypothesis& h = est.hypotheses.front();
  std::vector<std::string> written;
  std::vector<SuperquadricShape> shapes;
  std::vector<bool> truncated;
  for (size_t k = 0; k < h.instances.size(); ++k) {
    shapes.push_back(h.instances[k].superquadric);
    truncated.push_back(h.instances[k].truncated);
    const std::string name = "instance_" + std::to_string(k) + ".ply";
    writeMeshPly((out / name).string(), h.instances[k].mesh);
    written.push_back(name);
  }
  writeSuperquadricsYaml(
      (out / "superquadrics.yaml").string(), shapes, "table", truncated,
      one_view ? std::optional<Vec3>(est.T_table_camera.translation()) : std::nullopt);
  writeMeshPly((out / "surface.ply").string(),
               h.surface.empty() ? extractSurface(h.tsdf_m) : h.surface);
  writeVisibleInstances(out, view, est, min_height_m);
  writeGrids(out, est);
  renderShapes((out / "superquadrics_input_view.png").string(), shapes, view.camera,
               est.T_table_camera);
  const GridSpec& g = est.grid;
  const Vec3 centre(g.origin_table.x() + 0.5 * g.extent_m(),
                    g.origin_table.y() + 0.5 * g.extent_m(), 0.0);
  Transform turn = Transform::Identity();
  turn.translation() = centre;
  turn.rotate(Eigen::AngleAxisd(M_PI / 2, Vec3::UnitZ()));
  turn.translate(-centre);
  renderShapes((out / "superquadrics_second_view.png").string(), shapes, view.camera,
               turn * est.T_table_camera);
  for (const char* name : {"superquadrics.yaml", "surface.ply", "instances.pcd", "labels.png",
                           "depth.png", "instances.png", "grids.h5", "superquadrics_input_view.png",
                           "superquadrics_second_view.png"})
    written.push_back(name);
  return written;
}

}  // namespace simstack
