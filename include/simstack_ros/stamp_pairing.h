#pragma once
/// @file stamp_pairing.h
/// Pairs two message streams by exact stamp (a depth image with its camera_info), as
/// message_filters' ExactTime policy does, but forgets pending messages by arrival rather
/// than by stamp. ExactTime, when its queue is full, drops the pending message with the
/// oldest stamp; a half pair stamped later than every message still to come (a bag played in
/// a loop, back at its start, its last camera_info without the image) then stays for ever and
/// every new pair is dropped in its favour. Here the message that arrived first goes first,
/// so any number of such half pairs is gone after `pending` newer messages of its stream, and
/// a pair that completes takes every message that arrived before its older half with it.
/// Not thread-safe: the caller holds a lock.

#include <cstddef>
#include <cstdint>
#include <deque>
#include <optional>
#include <utility>

namespace simstack {

template <class First, class Second>
class StampPairing {
 public:
  /// Up to `pending` unpaired messages kept per stream (at least 1).
  explicit StampPairing(std::size_t pending) : pending_(pending < 1 ? 1 : pending) {}

  /// A message of the first stream; the pair it completes, if any.
  std::optional<std::pair<First, Second>> addFirst(std::uint64_t stamp_ns, First message) {
    return add(&firsts_, &seconds_, stamp_ns, std::move(message),
               [](First f, Second s) { return std::make_pair(std::move(f), std::move(s)); });
  }

  /// A message of the second stream; the pair it completes, if any.
  std::optional<std::pair<First, Second>> addSecond(std::uint64_t stamp_ns, Second message) {
    return add(&seconds_, &firsts_, stamp_ns, std::move(message),
               [](Second s, First f) { return std::make_pair(std::move(f), std::move(s)); });
  }

  /// Unpaired messages forgotten so far (pushed out by newer ones, or older than a pair).
  long forgotten() const { return forgotten_; }
  std::size_t pendingFirst() const { return firsts_.size(); }
  std::size_t pendingSecond() const { return seconds_.size(); }

 private:
  template <class M>
  struct Entry {
    std::uint64_t stamp_ns;
    std::uint64_t arrival;
    M message;
  };

  template <class Mine, class Other, class MakePair>
  std::optional<std::pair<First, Second>> add(std::deque<Entry<Mine>>* mine,
                                              std::deque<Entry<Other>>* other,
                                              std::uint64_t stamp_ns, Mine message,
                                              MakePair make_pair) {
    std::optional<Entry<Other>> match = take(other, stamp_ns);
    if (!match) {
      keep(mine, Entry<Mine>{stamp_ns, arrivals_++, std::move(message)});
      return std::nullopt;
    }
    forgetBefore(match->arrival);
    return make_pair(std::move(message), std::move(match->message));
  }

  template <class M>
  static std::optional<Entry<M>> take(std::deque<Entry<M>>* entries, std::uint64_t stamp_ns) {
    for (auto it = entries->begin(); it != entries->end(); ++it)
      if (it->stamp_ns == stamp_ns) {
        Entry<M> found = std::move(*it);
        entries->erase(it);
        return found;
      }
    return std::nullopt;
  }

  template <class M>
  void keep(std::deque<Entry<M>>* entries, Entry<M> entry) {
    entries->push_back(std::move(entry));
    while (entries->size() > pending_) {
      entries->pop_front();
      ++forgotten_;
    }
  }

  /// Streams come in stamp order: what arrived before a pair's older half will find no partner.
  void forgetBefore(std::uint64_t arrival) {
    while (!firsts_.empty() && firsts_.front().arrival < arrival) {
      firsts_.pop_front();
      ++forgotten_;
    }
    while (!seconds_.empty() && seconds_.front().arrival < arrival) {
      seconds_.pop_front();
      ++forgotten_;
    }
  }

  std::size_t pending_;
  std::deque<Entry<First>> firsts_;
  std::deque<Entry<Second>> seconds_;
  std::uint64_t arrivals_ = 0;
  long forgotten_ = 0;
};

}  // namespace simstack
