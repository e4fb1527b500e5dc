#pragma once
/// @file view_history.h
/// The posed views a live perception fuses (the paper's section 4.2): each new frame is
/// perceived with the newest views kept before it, up to a number of views in all. Views of
/// another time are never fused: a frame stamped before the last one (a bag that restarted or
/// loops, a second publisher) clears what was kept.

#include <cstddef>
#include <cstdint>
#include <deque>
#include <vector>

#include "simstack/geometry/depth_view.h"

namespace simstack {

class ViewHistory {
 public:
  /// `max_views`: views fused at most, the new one included (1: each frame alone).
  explicit ViewHistory(int max_views = 1) { setMaxViews(max_views); }
  /// Throws std::invalid_argument below 1. Views beyond a lowered limit go at the next keep().
  void setMaxViews(int max_views);
  int maxViews() const { return max_views_; }

  /// What a frame's stamp did to the history.
  struct Arrival {
    bool went_back = false;  ///< stamped before the last frame
    double back_s = 0.0;     ///< by how much
    size_t cleared = 0;      ///< kept views dropped for it
  };
  /// A frame stamped `stamp_ns` arrives (before viewsWith): one stamped before the last clears
  /// the kept views.
  Arrival arrive(int64_t stamp_ns);
  /// `view` first (it places the grid and conditions the network), then the newest kept views,
  /// at most maxViews() in all. An unposed view (the table estimated from its own depth) is
  /// perceived alone.
  std::vector<DepthView> viewsWith(const DepthView& view) const;
  /// Keeps a view that was perceived (a posed one), for the next frames: the newest
  /// maxViews() - 1 are kept.
  void keep(DepthView view);
  void clear() { views_.clear(); }
  size_t size() const { return views_.size(); }

 private:
  int max_views_ = 1;
  bool stamped_ = false;
  int64_t last_stamp_ns_ = 0;
  std::deque<DepthView> views_;  ///< oldest first
};

}  // namespace simstack
