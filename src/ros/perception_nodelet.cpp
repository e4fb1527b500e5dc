// simstack/PerceptionNodelet: PerceptionServer inside a nodelet manager.
#include <nodelet/nodelet.h>
#include <ros/package.h>
#include <pluginlib/class_list_macros.hpp>

#include <memory>

#include "simstack_ros/perception_server.h"

namespace simstack {

class PerceptionNodelet : public nodelet::Nodelet {
 private:
  void onInit() override {
    try {
      server_ = std::make_unique<PerceptionServer>(getMTNodeHandle(), getMTPrivateNodeHandle(),
                                                   ros::package::getPath("simstack"));
    } catch (const std::exception& e) {
      // Reported, and the manager with its other nodelets keeps running.
      NODELET_FATAL("simstack perception not started: %s", e.what());
      refused_ = std::make_unique<RefusedPerception>(getMTNodeHandle(), getMTPrivateNodeHandle(),
                                                     e.what());
    }
  }
  std::unique_ptr<PerceptionServer> server_;
  std::unique_ptr<RefusedPerception> refused_;  ///< ~ready false and the reason, when refused
};

}  // namespace simstack

PLUGINLIB_EXPORT_CLASS(simstack::PerceptionNodelet, nodelet::Nodelet)
