// rostest (test/ros/frozen_clock.test): perception nodelets on simulated time whose /clock
// stands still, as while a replayed bag is paused. A frame whose table transform is missing is
// skipped after tf_timeout_s of wall time, and a nodelet that is waiting for one unloads at
// once.
#include <diagnostic_msgs/DiagnosticArray.h>
#include <gtest/gtest.h>
#include <nodelet/NodeletUnload.h>
#include <ros/ros.h>
#include <rosgraph_msgs/Clock.h>

#include <functional>
#include <future>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>

#include "../test_scenes.h"
#include "simstack_ros/conversions.h"

namespace simstack {
namespace {

/// Polls `done` on the wall clock (simulated time stands still here) for up to `seconds`.
bool waitWall(const std::function<bool()>& done, double seconds) {
  const ros::WallTime end = ros::WallTime::now() + ros::WallDuration(seconds);
  while (!done()) {
    if (ros::WallTime::now() > end) return false;
    ros::WallDuration(0.02).sleep();
  }
  return true;
}

TEST(FrozenClock, AMissingTransformIsReportedAndAWaitingNodeletUnloads) {
  ros::NodeHandle nh;
  ros::Publisher clock = nh.advertise<rosgraph_msgs::Clock>("/clock", 1, true);
  rosgraph_msgs::Clock now;
  now.clock = ros::Time(100.0);
  clock.publish(now);

  std::mutex mutex;
  std::string quick_status;
  bool patient_waiting = false;  // its frame received, neither processed nor skipped
  ros::Subscriber diagnostics = nh.subscribe<diagnostic_msgs::DiagnosticArray>(
      "/diagnostics", 50, [&](const diagnostic_msgs::DiagnosticArray::ConstPtr& msg) {
        for (const auto& s : msg->status) {
          std::lock_guard<std::mutex> lock(mutex);
          if (s.name.rfind("quick/perception:", 0) == 0)  // named without the leading slash
            quick_status = s.message;
          if (s.name.rfind("patient/perception:", 0) != 0) continue;
          std::map<std::string, std::string> values;
          for (const auto& kv : s.values) values[kv.key] = kv.value;
          patient_waiting = values["frames received"] == "1" && values["frames processed"] == "0" &&
                            values["frames skipped (bad input)"] == "0";
        }
      });

  // A 1 m flat view from a camera frame that tf has never heard of.
  const PinholeCamera camera = test::centredCamera(160, 120, 130.0);
  DepthImage depth(camera.width, camera.height, 1.0f);
  std_msgs::Header header;
  header.stamp = now.clock;
  header.frame_id = "lost_camera";
  std::vector<ros::Publisher> publishers;
  for (const char* ns : {"/quick", "/patient"}) {
    publishers.push_back(
        nh.advertise<sensor_msgs::Image>(std::string(ns) + "/depth/image_rect", 1, true));
    publishers.push_back(
        nh.advertise<sensor_msgs::CameraInfo>(std::string(ns) + "/depth/camera_info", 1, true));
  }
  ASSERT_TRUE(waitWall(
      [&] {
        for (const ros::Publisher& p : publishers)
          if (p.getNumSubscribers() == 0) return false;
        return true;
      },
      60.0))
      << "the nodelets never subscribed";
  // The patient nodelet's wait for its transform ends by itself tf_timeout_s (10 s) of wall
  // time after its frame arrives: no earlier than this plus 10 s.
  const ros::WallTime published = ros::WallTime::now();
  for (size_t i = 0; i < publishers.size(); i += 2) {
    publishers[i].publish(depthImageMsg(header, depth));
    publishers[i + 1].publish(cameraInfoMsg(header, camera));
  }

  // The patient nodelet (tf_timeout_s 10) waits for its transform once its diagnostics count
  // its frame received and neither processed nor skipped: unloading it must end the wait
  // instead of waiting for the clock, so the unload is answered before the wait would have
  // ended by itself (10 s after the frame arrived). A thread of its own, left behind if it
  // hangs.
  const double patient_wait_s = 10.0;
  ASSERT_TRUE(waitWall(
      [&] {
        std::lock_guard<std::mutex> lock(mutex);
        return patient_waiting;
      },
      patient_wait_s - 3.0))
      << "the patient nodelet's diagnostics never showed its frame waiting for tf";
  auto answered = std::make_shared<std::promise<bool>>();
  std::future<bool> answer = answered->get_future();
  std::thread([answered] {
    nodelet::NodeletUnload unload;
    unload.request.name = "/patient/perception";
    const bool called = ros::service::call("/manager/unload_nodelet", unload);
    answered->set_value(called && unload.response.success);
  }).detach();
  const double left_s = patient_wait_s - 0.5 - (ros::WallTime::now() - published).toSec();
  ASSERT_EQ(answer.wait_for(std::chrono::duration<double>(left_s)), std::future_status::ready)
      << "unloading a nodelet that waits for tf hangs while /clock stands still (no answer "
      << patient_wait_s - 0.5 << " s after its frame)";
  EXPECT_TRUE(answer.get());

  // The simulated clock stands still for tf_timeout_s (0.5 s) of wall time: the skip is
  // reported (diagnostics come on a wall timer, once a second).
  std::string last_status;
  const bool reported = waitWall(
      [&] {
        std::lock_guard<std::mutex> lock(mutex);
        last_status = quick_status;
        return last_status.find("no transform") != std::string::npos;
      },
      15.0);
  EXPECT_TRUE(reported) << "the missing transform was never reported; last status: '" << last_status
                        << "'";
}

}  // namespace
}  // namespace simstack

int main(int argc, char** argv) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, "test_frozen_clock");
  ros::AsyncSpinner spinner(2);
  spinner.start();
  const int failed = RUN_ALL_TESTS();
  ros::shutdown();
  return failed;
}
