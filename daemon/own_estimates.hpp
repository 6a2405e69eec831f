#pragma once
// Telling this daemon's own estimates from another publisher's on the estimate channel (issue 10
// item 6, issue 12): two daemons on one window channel, or a shard configured twice, answer the
// same windows; LCM delivers both answers to everyone, and nothing else would notice.
//
// How an estimate is recognised as this process's own: by what it published, not by a tag in the
// message. The daemon remembers a 64-bit digest (FNV-1a) of the bytes of every estimate it
// publishes; the first copy of those bytes that comes back on the channel is its own echo (LCM's
// multicast loopback, memq) and is crossed off. Anything else for a window of its own share is
// foreign: a second copy of the same bytes too, so even two bit-identical answers are counted once.
// A tag (an instance id appended to force_estimate_t) would change the message's LCM fingerprint,
// and every program and archived log written against SPEC's force_estimate_t would stop decoding.
//
// Memory is bounded: a digest is kept `keep` long (its echo comes back within milliseconds) and at
// most `max_entries` are kept. A digest that ages out unechoed costs nothing but its slot; it can
// only make a later identical foreign estimate look like an echo, which needs a 64-bit collision.
// Touched by the IO thread only.
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <unordered_map>

namespace tipforce::daemon {

class OwnEstimates {
 public:
  using Clock = std::chrono::steady_clock;

  explicit OwnEstimates(Clock::duration keep = std::chrono::seconds(30), std::size_t max_entries = 1 << 16)
      : keep_(keep), max_entries_(max_entries) {}

  // This process published an estimate with this digest.
  void published(std::uint64_t digest, Clock::time_point now = Clock::now()) {
    expire(now);
    if (order_.size() >= max_entries_) forget_oldest();
    order_.push_back({now, digest});
    ++outstanding_[digest];
  }

  // An estimate with this digest came in on the channel: true (and crossed off) if it is the echo
  // of one of ours, false if another publisher sent it.
  bool take_echo(std::uint64_t digest, Clock::time_point now = Clock::now()) {
    expire(now);
    auto it = outstanding_.find(digest);
    if (it == outstanding_.end()) return false;
    if (--it->second == 0) outstanding_.erase(it);
    return true;
  }

  std::size_t outstanding() const {
    std::size_t n = 0;
    for (const auto& [digest, count] : outstanding_) n += static_cast<std::size_t>(count);
    return n;
  }

 private:
  struct Entry {
    Clock::time_point when;
    std::uint64_t digest;
  };
  void expire(Clock::time_point now) {
    while (!order_.empty() && now - order_.front().when > keep_) forget_oldest();
  }
  void forget_oldest() {
    // The entry may have been crossed off already (its echo came); then there is nothing to undo.
    auto it = outstanding_.find(order_.front().digest);
    if (it != outstanding_.end() && --it->second == 0) outstanding_.erase(it);
    order_.pop_front();
  }

  Clock::duration keep_;
  std::size_t max_entries_;
  std::deque<Entry> order_;
  std::unordered_map<std::uint64_t, int> outstanding_;
};

}  // namespace tipforce::daemon
