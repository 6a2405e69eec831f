#pragma once
// Rate limiting for warnings about bad input: at most `burst` lines per `interval`; what is held
// back is counted and reported with the next line let through. Single-threaded (IO thread).
#include <chrono>
#include <cstdint>

namespace tipforce::daemon {

class RateLimiter {
 public:
  using Clock = std::chrono::steady_clock;

  RateLimiter(int burst, Clock::duration interval) : burst_(burst), interval_(interval) {}

  // True if a line may be logged now. When true, suppressed() tells how many were held back
  // since the last line let through (and resets that count).
  bool allow(Clock::time_point now = Clock::now()) {
    if (now - window_start_ >= interval_) {
      window_start_ = now;
      used_ = 0;
    }
    if (used_ < burst_) {
      ++used_;
      return true;
    }
    ++suppressed_;
    return false;
  }

  std::int64_t take_suppressed() {
    const std::int64_t n = suppressed_;
    suppressed_ = 0;
    return n;
  }

 private:
  int burst_;
  Clock::duration interval_;
  Clock::time_point window_start_{};
  int used_ = 0;
  std::int64_t suppressed_ = 0;
};

}  // namespace tipforce::daemon
