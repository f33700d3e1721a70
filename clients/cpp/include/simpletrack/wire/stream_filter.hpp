// simpletrack::StreamFilter: which tracks messages a reader delivers, per stream (a sample's
// key: one sensor's `<prefix>/<vehicle>/<sensor>/tracks`, or a fused vehicle's
// `<prefix>/<vehicle>/@vehicle/tracks`). Not a message of a fenced holder, whose custody epoch
// is below the highest the stream has shown (EpochFilter); not an exact repeat of a recent
// (seq, stamp_ns); and, after custody moved, not the new holder's replay up to the last message
// (by stamp, then seq) delivered from the holder before it (schemas/README.md, "Custody epoch
// (fencing)"). The rule of the Python and Rust subscribers, verdict for verdict. In a zenoh-cpp
// subscriber:
//
//   simpletrack::StreamFilter filter;  // one per subscriber
//   auto fused = wire::decode_vehicle_track_frame(data, size);
//   if (fused && filter.admit(key, fused->seq, fused->stamp_ns, fused->epoch) ==
//                    simpletrack::Verdict::deliver) { /* use it */ }
//
// Not synchronised: call it under a lock when samples may come on several threads.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <optional>
#include <string>
#include <string_view>
#include <unordered_map>
#include <utility>

#include "simpletrack/wire/epoch_filter.hpp"

namespace simpletrack {

enum class Verdict {
  deliver,
  repeat,  // (seq, stamp_ns) delivered on this stream within the window, or a new holder's
           // replay of what the holder before it delivered
  stale,   // an epoch below the stream's highest: sent by a fenced holder
};

class StreamFilter {
 public:
  static constexpr std::size_t kRecentFrames = 16;  // per key: a repeat comes within a takeover
  static constexpr std::size_t kMaxKeys = 100'000;  // past it the filter starts afresh

  explicit StreamFilter(std::size_t recent_frames = kRecentFrames, std::size_t max_keys = kMaxKeys)
      : recent_frames_(std::max<std::size_t>(recent_frames, 1)),
        max_keys_(std::max<std::size_t>(max_keys, 1)) {}

  // The verdict on a message of stream `key`; a delivered one is remembered. A message without
  // an epoch (a service of before epochs) is judged as a repeat or not only, and leaves the
  // stream's highest epoch as it was. A new holder's epoch is its stream's highest from its
  // first message on, even when that message is a repeat.
  Verdict admit(std::string_view key, std::uint64_t seq, std::uint64_t stamp_ns,
                std::optional<std::uint64_t> epoch) {
    const std::string k(key);
    if (streams_.find(k) == streams_.end() && streams_.size() >= max_keys_) {
      streams_.clear();
      epochs_ = EpochFilter();
    }
    const std::optional<std::uint64_t> before = epochs_.highest(k);
    if (!epochs_.accept(k, epoch)) {
      ++stale_;
      return Verdict::stale;
    }
    Stream& s = streams_[k];
    if (epoch && before && *epoch > *before) {
      s.handover = s.recent.empty() ? std::nullopt : std::make_optional(s.recent.back());
    }
    const bool caught_up = !s.handover || std::make_pair(stamp_ns, seq) > *s.handover;
    const bool seen =
        std::find(s.recent.begin(), s.recent.end(), std::make_pair(stamp_ns, seq)) != s.recent.end();
    if (seen || (epoch && !caught_up)) {
      ++repeats_;
      return Verdict::repeat;
    }
    s.handover.reset();
    if (s.recent.size() >= recent_frames_) s.recent.pop_front();
    s.recent.emplace_back(stamp_ns, seq);
    return Verdict::deliver;
  }

  // The highest epoch `key` has shown; nullopt when none (or forgotten).
  std::optional<std::uint64_t> highest_epoch(std::string_view key) const {
    return epochs_.highest(key);
  }

  std::uint64_t repeats() const { return repeats_; }  // messages refused as repeats
  std::uint64_t stale() const { return stale_; }      // messages refused as stale

 private:
  struct Stream {
    // (stamp_ns, seq) delivered, the last one last.
    std::deque<std::pair<std::uint64_t, std::uint64_t>> recent;
    // After the epoch rose: the last message delivered from the holder before; the new
    // holder's messages at or before it are repeats. By (stamp, seq): a fused vehicle's lidar
    // and camera frames can share a stamp, each its own message. nullopt: caught up.
    std::optional<std::pair<std::uint64_t, std::uint64_t>> handover;
  };

  std::size_t recent_frames_;
  std::size_t max_keys_;
  EpochFilter epochs_;
  std::unordered_map<std::string, Stream> streams_;
  std::uint64_t repeats_ = 0;
  std::uint64_t stale_ = 0;
};

}  // namespace simpletrack
