#pragma once
/// @file sensor_option.h
/// The tools' `--sensor NAME` option: whose noise the rendered views get.

#include <CLI/CLI.hpp>

#include <string>

#include "simstack/render/depth_renderer.h"

namespace simstack {

/// Adds `--sensor` (kinect or realsense) to `app`, setting `*model` when given; returns the
/// option so a tool can tie it to its noise flag (`needs`, `excludes`).
inline CLI::Option* addSensorOption(CLI::App& app, SensorModel* model, const std::string& lead) {
  return app
      .add_option_function<std::string>(
          "--sensor", [model](const std::string& name) { *model = parseSensorModel(name); },
          lead +
              "whose noise: kinect (a 640x480 structured-light camera) or realsense (a D435 at "
              "1280x720: stereo noise growing with the square of the depth, holes beside depth "
              "edges, nothing nearer than 0.28 m)")
      ->default_str(sensorModelName(*model))
      ->check(CLI::IsMember({"kinect", "realsense"}));
}

}  // namespace simstack
