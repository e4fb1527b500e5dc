#include "simstack/io/octomap_io.h"

#include <octomap/OcTree.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <sstream>
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
  std::ostringstream bytes;
  const bool serialised = ext == ".ot" ? tree.write(bytes) : tree.writeBinary(bytes);
  if (!serialised)
    throw std::runtime_error("cannot write " + path + ": OctoMap serialisation failed");
  // A new file of a unique name beside the target (O_EXCL: never an existing file or a link
  // planted there), renamed over the target when complete.
  std::string temp = path + ".XXXXXX";
  const int fd = ::mkstemp(temp.data());
  if (fd < 0) throw std::runtime_error("cannot write " + path + ": " + std::strerror(errno));
  ::fchmod(fd, 0644);  // mkstemp's 0600 would hide the map from other users
  const std::string data = bytes.str();
  size_t done = 0;
  while (done < data.size()) {
    const ssize_t n = ::write(fd, data.data() + done, data.size() - done);
    if (n <= 0) break;
    done += static_cast<size_t>(n);
  }
  const bool complete = done == data.size() && ::fsync(fd) == 0;
  ::close(fd);
  std::error_code ec;
  if (complete) std::filesystem::rename(temp, path, ec);
  if (!complete || ec) {
    std::filesystem::remove(temp);
    throw std::runtime_error("cannot write " + path + (ec ? ": " + ec.message() : ""));
  }
}

}  // namespace simstack
