#include "simstack_ros/conversions.h"

#include <sensor_msgs/image_encodings.h>

#include <cmath>
#include <cstring>
#include <stdexcept>
#include <string>

namespace simstack {

DepthImage depthFromImage(const sensor_msgs::Image& msg) {
  namespace enc = sensor_msgs::image_encodings;
  const bool mm = msg.encoding == enc::TYPE_16UC1 || msg.encoding == enc::MONO16;
  const bool metres = msg.encoding == enc::TYPE_32FC1;
  if (!mm && !metres) {
    throw std::invalid_argument("depth encoding '" + msg.encoding +
                                "' is not supported (use 16UC1 in mm or 32FC1 in m)");
  }
  if (msg.is_bigendian) throw std::invalid_argument("big-endian depth images are not supported");
  if (msg.width == 0 || msg.height == 0) throw std::invalid_argument("depth image is empty");
  const size_t bytes = mm ? 2 : 4;
  if (msg.step < msg.width * bytes) {
    throw std::invalid_argument("depth image step " + std::to_string(msg.step) +
                                " is smaller than width x " + std::to_string(bytes) + " bytes");
  }
  if (msg.data.size() < static_cast<size_t>(msg.step) * msg.height) {
    throw std::invalid_argument("depth image holds " + std::to_string(msg.data.size()) +
                                " bytes, expected " +
                                std::to_string(static_cast<size_t>(msg.step) * msg.height));
  }
  DepthImage depth(static_cast<int>(msg.width), static_cast<int>(msg.height), 0.0f);
  for (uint32_t v = 0; v < msg.height; ++v) {
    const uint8_t* row = msg.data.data() + static_cast<size_t>(v) * msg.step;
    for (uint32_t u = 0; u < msg.width; ++u) {
      float d;
      if (mm) {
        uint16_t raw;
        std::memcpy(&raw, row + 2 * u, 2);
        d = raw * 0.001f;
      } else {
        std::memcpy(&d, row + 4 * u, 4);
      }
      depth.at(u, v) = validDepth(d) ? d : 0.0f;
    }
  }
  return depth;
}

PinholeCamera cameraFromInfo(const sensor_msgs::CameraInfo& msg) {
  PinholeCamera c;
  c.width = static_cast<int>(msg.width);
  c.height = static_cast<int>(msg.height);
  const bool has_p = msg.P[0] != 0.0 && msg.P[5] != 0.0;
  c.fx = has_p ? msg.P[0] : msg.K[0];
  c.fy = has_p ? msg.P[5] : msg.K[4];
  c.cx = has_p ? msg.P[2] : msg.K[2];
  c.cy = has_p ? msg.P[6] : msg.K[5];
  c.validate();
  return c;
}

}  // namespace simstack
