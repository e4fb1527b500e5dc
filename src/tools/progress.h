#pragma once
/// @file progress.h
/// A text progress bar for the command-line tools (stderr; redraws only on a terminal). The
/// library reports progress through callbacks; only the tools draw it.

#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <string>

namespace simstack {

class ProgressBar {
 public:
  /// `first`: the count already done when this run began (a resumed job), so that the time
  /// left is estimated from this run's pace; `elapsed_s`: the seconds this run has already
  /// spent (a bar made at the first report of the work).
  ProgressBar(std::string label, long total, long first = 0, double elapsed_s = 0.0)
      : label_(std::move(label)),
        total_(total),
        first_(first),
        tty_(isatty(fileno(stderr))),
        start_(std::chrono::steady_clock::now() -
               std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                   std::chrono::duration<double>(elapsed_s))) {}
  /// Shows `done` of `total`, with an optional suffix (e.g. current losses).
  void update(long done, const std::string& suffix = "") {
    const auto now = std::chrono::steady_clock::now();
    const double elapsed = std::chrono::duration<double>(now - start_).count();
    // On a terminal redraw at most 10 times a second; in a log, write a line every 10 %.
    if (tty_) {
      if (done < total_ && std::chrono::duration<double>(now - last_).count() < 0.1) return;
    } else if (done < total_ && done * 10 / total_ == last_decile_) {
      return;
    }
    last_ = now;
    last_decile_ = done * 10 / total_;
    const int width = 30;
    const int filled = total_ > 0 ? static_cast<int>(width * done / total_) : width;
    const double eta = done > first_ ? elapsed * (total_ - done) / (done - first_) : 0.0;
    std::fprintf(stderr, "%s%s [%s%s] %ld/%ld  %.0fs elapsed, %.0fs left %s%s", tty_ ? "\r" : "",
                 label_.c_str(), std::string(filled, '#').c_str(),
                 std::string(width - filled, '.').c_str(), done, total_, elapsed, eta,
                 suffix.c_str(), tty_ ? "\033[K" : "\n");
    std::fflush(stderr);
  }
  void finish() {
    if (tty_) std::fprintf(stderr, "\n");
  }

 private:
  std::string label_;
  long total_;
  long first_;
  bool tty_;
  std::chrono::steady_clock::time_point start_;
  std::chrono::steady_clock::time_point last_{};
  long last_decile_ = -1;
};

}  // namespace simstack
