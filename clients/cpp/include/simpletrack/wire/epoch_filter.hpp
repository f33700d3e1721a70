// simpletrack::EpochFilter: drops what a fenced holder of a tracks stream sends
// (schemas/README.md, "Custody epoch (fencing)"). Each time custody of a stream moves, the new
// holder publishes with a higher epoch (TrackFrame::epoch, VehicleTrackFrame::epoch); an
// instance that was paused or cut off may still publish with its old one, and a reader must
// not take that. Keep one filter per subscriber, keyed by the sample's key (one stream each):
//
//   simpletrack::EpochFilter fenced;
//   if (!fenced.accept(key, frame.epoch)) return;  // stale: drop, then apply the repeat rule
//
// Not synchronised: call it under the lock that guards the subscriber's other per-key state.
#pragma once

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <unordered_map>

namespace simpletrack {

class EpochFilter {
 public:
  // Streams remembered at most; past it the filter starts afresh, as the clients' repeat
  // filters do (a stream forgotten so takes its next epoch as its highest).
  static constexpr std::size_t kMaxKeys = 100'000;

  // False when `epoch` is below the highest `key` has shown: the message comes from a fenced
  // holder; drop it. Otherwise true, and `epoch` is the stream's highest from now on. A
  // message without an epoch (a service of before epochs) is accepted and changes nothing; an
  // equal epoch is accepted (the repeat rule decides).
  bool accept(std::string_view key, std::optional<std::uint64_t> epoch) {
    if (!epoch) return true;
    const auto it = highest_.find(std::string(key));
    if (it != highest_.end()) {
      if (*epoch < it->second) return false;
      it->second = *epoch;
      return true;
    }
    if (highest_.size() >= kMaxKeys) highest_.clear();
    highest_.emplace(std::string(key), *epoch);
    return true;
  }

  // The highest epoch `key` has shown; nullopt when none (or forgotten).
  std::optional<std::uint64_t> highest(std::string_view key) const {
    const auto it = highest_.find(std::string(key));
    if (it == highest_.end()) return std::nullopt;
    return it->second;
  }

  std::size_t size() const { return highest_.size(); }

 private:
  std::unordered_map<std::string, std::uint64_t> highest_;
};

}  // namespace simpletrack
