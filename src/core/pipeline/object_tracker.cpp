#include "simstack/pipeline/object_tracker.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>
#include <string>
#include <tuple>

namespace simstack {
namespace {

Vec3 sortedAxes(const SuperquadricShape& sq) {
  Vec3 a = sq.scale_m;
  std::sort(a.data(), a.data() + 3);
  return a;
}

/// The largest factor between corresponding sorted semi-axes.
double sizeRatio(const Vec3& a, const Vec3& b) {
  double worst = 1.0;
  for (int i = 0; i < 3; ++i) {
    const double lo = std::min(a[i], b[i]), hi = std::max(a[i], b[i]);
    worst = std::max(worst, lo > 0.0 ? hi / lo : INFINITY);
  }
  return worst;
}

}  // namespace

void TrackerConfig::validate() const {
  const auto refuse = [](const char* what, double value) {
    std::ostringstream out;
    out << what << ", not " << value;
    throw std::invalid_argument(out.str());
  };
  if (!(std::isfinite(max_centre_distance_m) && max_centre_distance_m > 0.0))
    refuse("max_centre_distance_m must be finite and > 0", max_centre_distance_m);
  if (!(std::isfinite(max_size_ratio) && max_size_ratio >= 1.0))
    refuse("max_size_ratio must be finite and >= 1", max_size_ratio);
  if (!(min_overlap_share > 0.0 && min_overlap_share <= 1.0))
    refuse("min_overlap_share must lie in (0, 1]", min_overlap_share);
  if (max_missed_frames < 0 || max_missed_frames > 1000)
    refuse("max_missed_frames must lie in [0, 1000]", max_missed_frames);
}

ObjectTracker::ObjectTracker(const TrackerConfig& config) : config_(config) { config_.validate(); }

std::vector<uint32_t> ObjectTracker::assign(const std::vector<SuperquadricShape>& objects) {
  std::vector<Track> now(objects.size());
  for (size_t i = 0; i < objects.size(); ++i)
    now[i] = {0, objects[i], objects[i].T_table_object.translation(), sortedAxes(objects[i])};
  // Pass 0: centres within the gate; pass 1: shapes that overlap.
  std::vector<std::tuple<int, double, size_t, size_t>> pairs;  // pass, distance, new, previous
  for (size_t i = 0; i < now.size(); ++i)
    for (size_t j = 0; j < previous_.size(); ++j) {
      if (sizeRatio(now[i].sorted_axes, previous_[j].sorted_axes) > config_.max_size_ratio)
        continue;
      const double d = (now[i].centre - previous_[j].centre).norm();
      if (d <= config_.max_centre_distance_m)
        pairs.emplace_back(0, d, i, j);
      else if (sharedVolumeShare(now[i].shape, previous_[j].shape) >= config_.min_overlap_share)
        pairs.emplace_back(1, d, i, j);
    }
  std::sort(pairs.begin(), pairs.end());
  std::vector<bool> matched_new(now.size(), false), matched_old(previous_.size(), false);
  for (const auto& [pass, d, i, j] : pairs) {
    if (matched_new[i] || matched_old[j]) continue;
    matched_new[i] = matched_old[j] = true;
    now[i].id = previous_[j].id;
  }
  std::vector<uint32_t> ids(now.size());
  for (size_t i = 0; i < now.size(); ++i) {
    if (!matched_new[i]) now[i].id = next_id_++;
    ids[i] = now[i].id;
  }
  // The objects this frame missed wait, as last estimated, until they have been missed too often.
  for (size_t j = 0; j < previous_.size(); ++j)
    if (!matched_old[j] && previous_[j].missed < config_.max_missed_frames) {
      now.push_back(previous_[j]);
      ++now.back().missed;
    }
  previous_ = std::move(now);
  return ids;
}

void ObjectTracker::reset() { previous_.clear(); }

}  // namespace simstack
