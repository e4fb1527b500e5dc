/// Task code as a user's own package writes it against simstack's exported API: a box rendered
/// on the table is perceived, put into a RankGrasps request as the perception node would
/// publish it, and grasps on it are ranked. Exits 0 when the box is found where it stands and
/// at least one grasp is ranked; test/check_downstream.sh builds and runs it.

#include <cstdio>
#include <exception>

#include <simstack/RankGrasps.h>
#include <simstack/grasping/grasp_ranking.h>
#include <simstack/pipeline/scene_perception.h>
#include <simstack/render/depth_renderer.h>
#include <simstack_ros/conversions.h>
#include <simstack_ros/grasp_conversions.h>

int main(int argc, char** argv) {
  if (argc != 3) {
    std::fprintf(stderr, "usage: task_code PERCEPTION_YAML PACKAGE_DIR\n");
    return 2;
  }
  try {
    simstack::SuperquadricShape box;
    box.scale_m = {0.06, 0.04, 0.03};
    box.exponents = {10.0, 10.0, 10.0};
    box.T_table_object.translation() = simstack::Vec3(0.0, 0.0, 0.03);
    const simstack::DepthRenderer renderer(simstack::Scene::fromSuperquadrics({box}));
    simstack::DepthView view;
    view.T_table_camera = simstack::lookAt({0.45, -0.3, 0.55}, {0.0, 0.0, 0.03});
    view.depth = renderer.render(view.camera, *view.T_table_camera).depth;

    const simstack::ScenePerception perception(simstack::loadPerceptionYaml(argv[1], argv[2]));
    const simstack::SceneEstimate estimate = perception.perceive(view);
    std_msgs::Header header;
    header.frame_id = "table";
    simstack::RankGrasps srv;
    srv.request.scene = simstack::objectArrayMsg(header, estimate, 1, perception.config().samples,
                                                 perception.config().symmetries);
    srv.request.target_id = 0;
    if (srv.request.scene.objects.size() != 1) {
      std::fprintf(stderr, "expected one object, perceived %zu\n",
                   srv.request.scene.objects.size());
      return 1;
    }
    const auto scenes = simstack::graspScenes(srv.request.scene, 1);
    const double off =
        (scenes[0][0].T_table_object.translation() - box.T_table_object.translation()).norm();
    if (off > 0.03) {
      std::fprintf(stderr, "the box was perceived %.3f m from where it stands\n", off);
      return 1;
    }
    const simstack::GraspRanking ranking =
        simstack::rankGrasps(scenes, 0, {}, simstack::GraspRankingConfig());
    if (ranking.grasps.empty()) {
      std::fprintf(stderr, "no grasp ranked: %s\n", ranking.message.c_str());
      return 1;
    }
    srv.response.grasps.push_back(
        simstack::graspMsg(ranking.grasps.front(), header, simstack::Transform::Identity(), 0.05));
    std::printf("one box perceived %.3f m from where it stands; %zu grasps ranked\n", off,
                ranking.grasps.size());
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "task_code: %s\n", e.what());
    return 1;
  }
}
