#include "simstack/offline/eval/occupancy.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace simstack {

OccupancyScores scoreOccupancy(const std::vector<float>& gt,
                               const std::vector<std::vector<float>>& samples) {
  if (samples.empty()) throw std::invalid_argument("occupancy scores need at least one sample");
  for (const auto& s : samples) {
    if (s.size() != gt.size())
      throw std::invalid_argument("sample and ground truth grids differ in size");
  }
  constexpr double kClamp = 1e-3;  // a confident miss costs -log(1e-3) = 6.9, not infinity
  double bce = 0.0;
  long inter = 0, uni = 0;
  for (size_t i = 0; i < gt.size(); ++i) {
    double p = 0.0;
    for (const auto& s : samples) p += s[i] <= 0.0f ? 1.0 : 0.0;
    p /= static_cast<double>(samples.size());
    const bool y = gt[i] <= 0.0f;
    const double pc = std::clamp(p, kClamp, 1.0 - kClamp);
    bce -= y ? std::log(pc) : std::log(1.0 - pc);
    const bool pred = p > 0.5;
    inter += pred && y;
    uni += pred || y;
  }
  OccupancyScores s;
  s.bce = bce / static_cast<double>(gt.size());
  s.iou = uni > 0 ? static_cast<double>(inter) / uni : 1.0;
  return s;
}

}  // namespace simstack
