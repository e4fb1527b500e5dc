#include "simstack/grasping/grasp_files.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "simstack/io/image_io.h"
#include "simstack/render/depth_renderer.h"
#include "simstack/scene/scene.h"

namespace simstack {
namespace {

using nlohmann::json;

json vec(const Vec3& v) { return json::array({v.x(), v.y(), v.z()}); }

json poseJson(const Transform& T) {
  const Quat q(T.linear());
  const Vec3 t = T.translation();
  return json::array({t.x(), t.y(), t.z(), q.w(), q.x(), q.y(), q.z()});
}

json outcomeJson(const PullOutcome& o) {
  return {{"mean_displacement_m", o.mean_displacement_m},
          {"max_displacement_m", o.max_displacement_m},
          {"max_rotation_rad", o.max_rotation_rad},
          {"toppled", o.toppled},
          {"cup_held", o.cup_held},
          {"target_freed", o.target_freed},
          {"peak_force_n", o.peak_force_n},
          {"target_lift_m", o.target_lift_m}};
}

}  // namespace

std::string graspTable(const GraspRanking& r, int rows) {
  std::ostringstream out;
  char line[256];
  std::snprintf(line, sizeof line, "%4s  %-22s %-18s %5s %8s %8s %8s %7s %6s %6s\n", "rank",
                "contact (m)", "approach", "seal", "mean mm", "worst mm", "max mm", "toppled",
                "freed", "failed");
  out << line;
  const int n = std::min<int>(rows, static_cast<int>(r.grasps.size()));
  for (int i = 0; i < n; ++i) {
    const RankedGrasp& g = r.grasps[i];
    const Vec3 &c = g.candidate.contact_table, &a = g.candidate.approach_table;
    std::snprintf(line, sizeof line,
                  "%4d  %+6.3f %+6.3f %+6.3f  %+5.2f %+5.2f %+5.2f %5.2f %8.1f %8.1f %8.1f %7.2f "
                  "%6.2f %6.2f\n",
                  i + 1, c.x(), c.y(), c.z(), a.x(), a.y(), a.z(), g.candidate.seal_score,
                  1e3 * g.mean_displacement_m, 1e3 * g.worst_displacement_m,
                  1e3 * g.max_displacement_m, g.mean_toppled, g.freed_share, g.failed_share);
    out << line;
  }
  if (n < static_cast<int>(r.grasps.size())) out << "  ... " << r.grasps.size() - n << " more\n";
  for (size_t h = 0; h < r.baseline.size(); ++h) {
    std::snprintf(line, sizeof line,
                  "baseline (hypothesis %d left alone, once settled): objects moved %.1f mm at "
                  "most, %.1f mm on average",
                  r.hypotheses[h], 1e3 * r.baseline[h].max_displacement_m,
                  1e3 * r.baseline[h].mean_displacement_m);
    out << line;
    // A scene given above its table falls while it settles, before the baseline and any pull.
    if (r.baseline[h].presettle_displacement_m > SceneDrift::kMovedWhileSettling_m) {
      std::snprintf(line, sizeof line, "; while settling, up to %.0f mm",
                    1e3 * r.baseline[h].presettle_displacement_m);
      out << line;
    }
    out << "\n";
  }
  return out.str();
}

void writeGraspJson(const std::string& path, const GraspRanking& r, int target_id,
                    double pregrasp_distance_m) {
  json grasps = json::array();
  for (const RankedGrasp& g : r.grasps) {
    json outcomes = json::array();
    for (const PullOutcome& o : g.outcomes) outcomes.push_back(outcomeJson(o));
    const Transform tool = toolPose(g.candidate);
    grasps.push_back({{"tool_pose", poseJson(tool)},
                      {"pregrasp_pose", poseJson(pregraspPose(tool, pregrasp_distance_m))},
                      {"held", g.held()},
                      {"freed", g.freed()},
                      {"contact_m", vec(g.candidate.contact_table)},
                      {"approach", vec(g.candidate.approach_table)},
                      {"seal_score", g.candidate.seal_score},
                      {"seal_measured", g.candidate.measured},
                      {"rim_deviation_m", g.candidate.rim_deviation_m},
                      {"mean_displacement_m", g.mean_displacement_m},
                      {"worst_displacement_m", g.worst_displacement_m},
                      {"max_displacement_m", g.max_displacement_m},
                      {"mean_toppled", g.mean_toppled},
                      {"freed_share", g.freed_share},
                      {"failed_share", g.failed_share},
                      {"score_m", g.score_m},
                      {"perturbed_held_share",
                       std::isnan(g.copies_held_share) ? json(nullptr) : json(g.copies_held_share)},
                      {"com_offset_m", g.com_offset_m},
                      {"peak_load", g.peak_load},
                      {"per_hypothesis", outcomes}});
  }
  json baseline = json::array();
  for (const SceneDrift& d : r.baseline)
    baseline.push_back({{"mean_displacement_m", d.mean_displacement_m},
                        {"max_displacement_m", d.max_displacement_m},
                        {"presettle_displacement_m", d.presettle_displacement_m},
                        {"settled", d.settled}});
  const json doc = {{"target_id", target_id},
                    {"surface_samples", r.candidates.surface_samples},
                    {"visible", r.candidates.visible},
                    {"reachable", r.candidates.reachable},
                    {"sealable", r.candidates.sealable},
                    {"hypotheses", r.hypotheses},
                    {"pulls", r.pulls},
                    {"message", r.message},
                    {"baseline", baseline},
                    {"grasps", grasps}};
  std::ofstream f(path);
  f << doc.dump(1) << "\n";
  f.close();  // a failed flush shows only here
  if (!f) throw std::runtime_error("cannot write " + path);
}

void writeGraspPicture(const std::string& path, const std::vector<SuperquadricShape>& scene,
                       const std::vector<RankedGrasp>& grasps, int top) {
  Vec3 centre = Vec3::Zero();
  double reach = 0.1;
  for (const SuperquadricShape& sq : scene) centre += sq.centroid() / scene.size();
  for (const SuperquadricShape& sq : scene)
    reach = std::max(reach, (sq.centroid() - centre).norm() + sq.scale_m.maxCoeff());
  PinholeCamera camera;  // 640x480, the Kinect-like default
  const Transform T_table_camera = lookAt(centre + reach * Vec3(-1.5, -1.1, 1.6),
                                          Vec3(centre.x(), centre.y(), 0.3 * centre.z()));
  RenderConfig rc;
  rc.table_half_size_m = 5.0;
  const DepthRenderer renderer(Scene::fromSuperquadrics(scene), rc);
  const RenderResult image = renderer.render(camera, T_table_camera, SensorNoiseConfig(), true);
  std::vector<PictureArrow> arrows;
  const int n = std::min<int>(top, static_cast<int>(grasps.size()));
  for (int i = 0; i < n; ++i) {
    PictureArrow a;
    a.tip_table = grasps[i].candidate.contact_table;
    a.tail_table = a.tip_table + 0.06 * grasps[i].candidate.approach_table;
    a.colour = outcomeColour(graspOutcome(grasps[i])).cast<float>();
    a.label = std::to_string(i + 1);
    arrows.push_back(a);
  }
  writeShadedPicture(path, image.instances, image.normals_table, T_table_camera, camera, arrows);
}

}  // namespace simstack
