#pragma once
// What the model and the training tests share: a tiny network config and scratch paths.

#include <unistd.h>

#include <filesystem>
#include <string>
#include <system_error>
#include <vector>

#include "simstack/model/cvae_config.h"
#include "test_scenes.h"  // tempPath

namespace simstack::test {

inline CvaeConfig tiny(const std::string& architecture = "cvae") {
  CvaeConfig c;
  c.architecture = architecture;
  c.resolution = 16;
  c.base_channels = 4;
  c.max_channels = 16;
  c.latent_size = 8;
  c.condition_size = 8;
  c.hidden_size = 16;
  return c;
}

// Removes the paths when the test ends, also when an assertion returns early.
struct RemoveAtExit {
  std::vector<std::string> paths;
  ~RemoveAtExit() {
    std::error_code ec;
    for (const auto& p : paths) std::filesystem::remove_all(p, ec);
  }
};

}  // namespace simstack::test
