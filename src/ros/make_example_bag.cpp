// simstack_make_bag: a rosbag of synthetic depth frames of one generated pile, seen from a ring
// of viewpoints: depth/image_rect (16UC1, mm), depth/camera_info and tf from the table to the
// camera, as a depth camera on a robot would publish them. test/data/example_pile.bag was made
// with the defaults (README, "Running in ROS").
#include <geometry_msgs/TransformStamped.h>
#include <rosbag/bag.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/image_encodings.h>
#include <tf2_eigen/tf2_eigen.h>
#include <tf2_msgs/TFMessage.h>
#include <CLI/CLI.hpp>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstring>
#include <iostream>
#include <regex>
#include <utility>

#include "cli_checks.h"
#include "simstack/io/staged_output.h"
#include "simstack/offline/piles/pile_generator.h"
#include "simstack/render/depth_renderer.h"
#include "simstack_ros/conversions.h"

using namespace simstack;

namespace {

/// Why the camera namespace and frames cannot be used ("" when they can): a namespace of
/// names a replay can subscribe to (the topics are /<camera>/depth/...: letters, digits and
/// underscores, each name starting with a letter), frame ids tf2 takes (no leading '/', no
/// blank), the table and camera frames apart.
std::string badNames(const std::string& camera_ns, const std::string& table_frame,
                     const std::string& camera_frame) {
  if (camera_ns.empty() || table_frame.empty() || camera_frame.empty() ||
      table_frame == camera_frame)
    return "--camera, --table-frame and --camera-frame must not be empty, and the table and "
           "camera frames must differ";
  static const std::regex kNamespace("[A-Za-z][A-Za-z0-9_]*(/[A-Za-z][A-Za-z0-9_]*)*");
  if (!std::regex_match(camera_ns, kNamespace))
    return "--camera '" + camera_ns +
           "' is not a namespace of ROS names (letters, digits and '_', each name starting "
           "with a letter, joined by '/', no leading '/')";
  for (const auto& [option, frame] : {std::make_pair("--table-frame", &table_frame),
                                      std::make_pair("--camera-frame", &camera_frame)}) {
    if (frame->front() == '/')
      return std::string(option) + " '" + *frame + "': a tf2 frame id has no leading '/'";
    if (std::any_of(frame->begin(), frame->end(),
                    [](unsigned char c) { return std::isspace(c) || std::iscntrl(c); }))
      return std::string(option) + " '" + *frame + "': a frame id holds no blank";
  }
  return "";
}

}  // namespace

int main(int argc, char** argv) {
  std::string output, camera_ns = "camera", table_frame = "table",
                      camera_frame = "camera_depth_optical_frame";
  uint64_t seed = 2021;
  int views = 6, repeats = 2;
  double interval_s = 0.5, distance_m = 0.75, elevation_deg = 50.0;
  bool noise = true;
  CLI::App app{
      "Write a rosbag of one generated pile seen from a ring of viewpoints: depth images "
      "(16UC1, mm), camera_info and tf table -> camera, to replay into the perception node."};
  app.add_option("--output", output, "bag file")->required()->check(WritablePath);
  app.add_option("--seed", seed, "pile seed (simstack_generate's scene seeds)")
      ->capture_default_str()
      ->transform(SeedNumber);
  app.add_option("--views", views, "viewpoints on the ring")
      ->capture_default_str()
      ->check(CLI::Range(1, 64));
  app.add_option("--repeats", repeats, "frames per viewpoint")
      ->capture_default_str()
      ->check(CLI::Range(1, 100));
  app.add_option("--interval", interval_s, "seconds between frames")
      ->capture_default_str()
      ->check(FinitePositive)
      ->check(CLI::Range(0.01, 10.0));
  app.add_option("--distance", distance_m, "camera distance from the pile's centre (m)")
      ->capture_default_str()
      ->check(FinitePositive)
      ->check(CLI::Range(0.3, 3.0));
  app.add_option("--elevation", elevation_deg, "camera elevation above the table (degrees)")
      ->capture_default_str()
      ->check(FinitePositive)
      ->check(CLI::Range(5.0, 90.0));
  app.add_option("--camera", camera_ns, "camera namespace of the topics")->capture_default_str();
  app.add_option("--table-frame", table_frame, "tf frame of the table")->capture_default_str();
  app.add_option("--camera-frame", camera_frame, "tf frame of the depth camera (optical)")
      ->capture_default_str();
  app.add_flag("--noise,!--no-noise", noise, "Kinect-like sensor noise (on by default)");
  CLI11_PARSE(app, argc, argv);
  const std::string bad = badNames(camera_ns, table_frame, camera_frame);
  if (!bad.empty()) {
    std::cerr << "simstack_make_bag: error: " << bad << "\n";
    return 105;  // as CLI11's refusals of an option's value
  }
  try {
    const Scene scene = PileGenerator(PileConfig()).generate(seed).scene;
    const DepthRenderer renderer(scene);
    const Vec3 centre = scene.surfaceCentroid();
    const PinholeCamera camera;
    StagedFile staged(output);  // an earlier bag stays whole until this one is
    rosbag::Bag bag(staged.path(), rosbag::bagmode::Write);
    bag.setCompression(rosbag::compression::BZ2);
    const double elevation = elevation_deg * M_PI / 180.0;
    int frame = 0;
    for (int v = 0; v < views; ++v) {
      const double azimuth = 2.0 * M_PI * v / views;
      const Vec3 eye =
          centre + distance_m * Vec3(std::cos(elevation) * std::cos(azimuth),
                                     std::cos(elevation) * std::sin(azimuth), std::sin(elevation));
      const Transform T_table_camera = lookAt(eye, Vec3(centre.x(), centre.y(), 0.05));
      for (int r = 0; r < repeats; ++r, ++frame) {
        std_msgs::Header header;
        header.seq = frame;
        header.stamp = ros::Time(1.0 + frame * interval_s);
        header.frame_id = camera_frame;
        const RenderResult image = renderer.render(
            camera, T_table_camera,
            noise ? SensorNoiseConfig::kinect(seed * 1000 + frame) : SensorNoiseConfig());
        geometry_msgs::TransformStamped t = tf2::eigenToTransform(T_table_camera);
        t.header.stamp = header.stamp;
        t.header.frame_id = table_frame;
        t.child_frame_id = camera_frame;
        tf2_msgs::TFMessage tf;
        tf.transforms.push_back(t);
        bag.write("/tf", header.stamp, tf);
        bag.write("/" + camera_ns + "/depth/camera_info", header.stamp,
                  cameraInfoMsg(header, camera));
        bag.write("/" + camera_ns + "/depth/image_rect", header.stamp,
                  depthImageMsg(header, image.depth));
      }
    }
    bag.close();
    staged.commit();
    std::cout << "wrote " << frame << " frames (" << views << " viewpoints, "
              << scene.objects.size() << " objects, seed " << seed << ") to " << output << "\n";
    return 0;
  } catch (const std::exception& e) {
    std::cerr << "simstack_make_bag: error: " << e.what() << "\n";
    return 1;
  }
}
