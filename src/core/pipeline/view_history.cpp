#include "simstack/pipeline/view_history.h"

#include <algorithm>
#include <stdexcept>
#include <string>

namespace simstack {

void ViewHistory::setMaxViews(int max_views) {
  if (max_views < 1)
    throw std::invalid_argument("max_views must be >= 1, not " + std::to_string(max_views));
  max_views_ = max_views;
}

ViewHistory::Arrival ViewHistory::arrive(int64_t stamp_ns) {
  Arrival a;
  if (stamped_ && stamp_ns < last_stamp_ns_) {
    a.went_back = true;
    a.back_s = 1e-9 * static_cast<double>(last_stamp_ns_ - stamp_ns);
    a.cleared = views_.size();
    views_.clear();
  }
  stamped_ = true;
  last_stamp_ns_ = stamp_ns;
  return a;
}

std::vector<DepthView> ViewHistory::viewsWith(const DepthView& view) const {
  std::vector<DepthView> out{view};
  if (!view.T_table_camera) return out;
  const size_t older = std::min(views_.size(), static_cast<size_t>(max_views_ - 1));
  out.insert(out.end(), views_.rbegin(), views_.rbegin() + older);
  return out;
}

void ViewHistory::keep(DepthView view) {
  if (!view.T_table_camera) return;
  views_.push_back(std::move(view));
  // The next frame fuses at most max_views - 1 of them.
  while (static_cast<int>(views_.size()) > max_views_ - 1) views_.pop_front();
}

}  // namespace simstack
