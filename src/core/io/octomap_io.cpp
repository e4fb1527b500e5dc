#include "simstack/io/octomap_io.h"

#include <octomap/OcTree.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <stdexcept>

namespace simstack {

void writeOccupancyOctomap(const std::string& path, const Grid3<float>& probability,
                           double min_probability) {
  const std::string ext = std::filesystem::path(path).extension().string();
  if (ext != ".ot" && ext != ".bt")
    throw std::invalid_argument("an OctoMap file ends in .ot or .bt, not '" + ext + "': " + path);
  const GridSpec& g = probability.spec;
  if (static_cast<int>(probability.data.size()) != g.voxelCount())
    throw std::invalid_argument("writeOccupancyOctomap: the grid holds " +
                                std::to_string(probability.data.size()) + " values for " +
                                std::to_string(g.voxelCount()) + " voxels");
  octomap::OcTree tree(g.voxel_size_m);
  const double p_min = std::clamp(min_probability, 1e-3, 1.0 - 1e-3);
  tree.setOccupancyThres(p_min);
  tree.setClampingThresMin(1e-3);
  tree.setClampingThresMax(1.0 - 1e-3);
  for (int z = 0; z < g.resolution; ++z)
    for (int y = 0; y < g.resolution; ++y)
      for (int x = 0; x < g.resolution; ++x) {
        const Vec3 c = g.voxelCentre(x, y, z);
        const double p = std::clamp<double>(probability.data[g.linear(x, y, z)], 1e-3, 1 - 1e-3);
        tree.setNodeValue(c.x(), c.y(), c.z(), static_cast<float>(std::log(p / (1.0 - p))));
      }
  const std::string temp = path + ".tmp." + std::to_string(::getpid());
  const bool written = ext == ".ot" ? tree.write(temp) : tree.writeBinary(temp);
  std::error_code ec;
  if (!written) {
    std::filesystem::remove(temp, ec);
    throw std::runtime_error("cannot write " + path);
  }
  std::filesystem::rename(temp, path, ec);
  if (ec) {
    std::filesystem::remove(temp);
    throw std::runtime_error("cannot write " + path + ": " + ec.message());
  }
}

}  // namespace simstack
