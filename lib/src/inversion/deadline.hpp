#pragma once
// A window's latency budget as the stages see it: checked between batches (swarm generations,
// Levenberg-Marquardt tries), never inside one, so a fit stops at most one batch past it.
#include <chrono>
#include <optional>

namespace tipforce::inversion {

class Deadline {
 public:
  using Clock = std::chrono::steady_clock;
  Deadline() = default;  // none
  explicit Deadline(std::optional<Clock::time_point> at) : at_(at) {}
  bool passed() const { return at_ && Clock::now() >= *at_; }
  // Whether it passes within this many seconds from now (a stage that long, begun now, would end
  // past it).
  bool passes_within(double seconds) const {
    return at_ && Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(seconds)) >= *at_;
  }

 private:
  std::optional<Clock::time_point> at_;
};

}  // namespace tipforce::inversion
