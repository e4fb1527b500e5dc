// Load for the perception node (test/bench/bench_perception_node.sh): 640x480 16UC1 depth of a
// rendered pile with its camera_info, published at a fixed rate for a fixed time, every frame
// under a fresh stamp; measures the node's answers on ~objects (rate, latency from the image
// stamp, frames the node dropped) and its resident memory. Prints one JSON line.
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/image_encodings.h>
#include <simstack/ObjectArray.h>
#include <tf2_eigen/tf2_eigen.h>
#include <tf2_ros/static_transform_broadcaster.h>
#include <CLI/CLI.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <fstream>
#include <iostream>
#include <mutex>
#include <string>
#include <vector>

#include "simstack/offline/piles/pile_generator.h"
#include "simstack/render/depth_renderer.h"
#include "simstack_ros/conversions.h"

using namespace simstack;

namespace {

long rssKb(int pid) {
  std::ifstream status("/proc/" + std::to_string(pid) + "/status");
  for (std::string line; std::getline(status, line);)
    if (line.rfind("VmRSS:", 0) == 0) return std::stol(line.substr(6));
  return -1;
}

double percentile(std::vector<double> v, double q) {
  if (v.empty()) return std::nan("");
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<size_t>(q * (v.size() - 1) + 0.5))];
}

}  // namespace

int main(int argc, char** argv) {
  double rate_hz = 30.0, seconds = 60.0, early_s = 10.0;
  int pid = 0;
  std::string label = "idle";
  CLI::App app{"Publish depth frames into the perception node and measure its answers."};
  app.add_option("--rate", rate_hz, "frames per second")->capture_default_str();
  app.add_option("--seconds", seconds, "how long")->capture_default_str();
  app.add_option("--early", early_s, "when the first memory reading is taken (s)")
      ->capture_default_str();
  app.add_option("--pid", pid, "the node's process (for its memory)")->required();
  app.add_option("--label", label, "name of the case in the output")->capture_default_str();
  std::vector<std::string> ros_args;
  app.allow_extras();
  CLI11_PARSE(app, argc, argv);
  ros::init(argc, argv, "bench_node_driver", ros::init_options::AnonymousName);
  ros::NodeHandle nh;
  ros::Publisher image_pub = nh.advertise<sensor_msgs::Image>("/camera/depth/image_rect", 1);
  ros::Publisher info_pub = nh.advertise<sensor_msgs::CameraInfo>("/camera/depth/camera_info", 1);
  std::mutex mutex;
  std::vector<double> latency_s;
  long answered = 0;
  ros::Subscriber sub = nh.subscribe<ObjectArray>(
      "/camera/perception/objects", 100, [&](const ObjectArray::ConstPtr& msg) {
        const double l = (ros::Time::now() - msg->header.stamp).toSec();
        std::lock_guard<std::mutex> lock(mutex);
        latency_s.push_back(l);
        ++answered;
      });
  ros::AsyncSpinner spinner(1);
  spinner.start();

  const Scene scene = PileGenerator(PileConfig()).generate(2021).scene;
  const Vec3 c = scene.surfaceCentroid();
  const Transform T_table_camera = lookAt(c + Vec3(0.5, -0.35, 0.55), Vec3(c.x(), c.y(), 0.05));
  const PinholeCamera camera;
  const DepthImage depth = DepthRenderer(scene).render(camera, T_table_camera).depth;
  tf2_ros::StaticTransformBroadcaster tf;
  geometry_msgs::TransformStamped t = tf2::eigenToTransform(T_table_camera);
  t.header.stamp = ros::Time::now();
  t.header.frame_id = "table";
  t.child_frame_id = "camera_depth_optical_frame";
  tf.sendTransform(t);
  std_msgs::Header header;
  header.frame_id = t.child_frame_id;
  sensor_msgs::Image img = depthImageMsg(header, depth);
  sensor_msgs::CameraInfo info = cameraInfoMsg(header, camera);
  ros::WallDuration(2.0).sleep();  // connections

  long sent = 0, rss_early = -1;
  const ros::WallTime start = ros::WallTime::now();
  ros::WallRate rate(rate_hz);
  while (ros::ok() && (ros::WallTime::now() - start).toSec() < seconds) {
    img.header.stamp = info.header.stamp = ros::Time::now();
    img.header.seq = info.header.seq = static_cast<uint32_t>(sent);
    info_pub.publish(info);
    image_pub.publish(img);
    ++sent;
    if (rss_early < 0 && (ros::WallTime::now() - start).toSec() >= early_s) rss_early = rssKb(pid);
    rate.sleep();
  }
  const double elapsed = (ros::WallTime::now() - start).toSec();
  const long rss_end = rssKb(pid);
  ros::WallDuration(1.0).sleep();  // the last answer
  std::lock_guard<std::mutex> lock(mutex);
  std::cout << "{\"case\": \"" << label << "\", \"seconds\": " << elapsed << ", \"sent\": " << sent
            << ", \"answered\": " << answered << ", \"answers_per_s\": " << answered / elapsed
            << ", \"not_answered\": " << sent - answered
            << ", \"latency_median_ms\": " << 1000 * percentile(latency_s, 0.5)
            << ", \"latency_p95_ms\": " << 1000 * percentile(latency_s, 0.95)
            << ", \"rss_early_mb\": " << rss_early / 1024.0
            << ", \"rss_end_mb\": " << rss_end / 1024.0 << "}" << std::endl;
  return 0;
}
