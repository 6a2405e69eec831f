#pragma once
// tipforced's counters and per-period latency statistics, turned into latency_stats_t.
// Touched only by the IO thread (no locking).
#include <cstdint>
#include <string>
#include <vector>

#include "tipforce/latency_stats_t.hpp"

namespace tipforce::daemon {

class LatencyStats {
 public:
  // Cumulative counters since start (never reset).
  struct Totals {
    std::int64_t received = 0;  // every message on the window channel
    std::int64_t done = 0;      // estimates published (any status, STATUS_REJECTED included)
    std::int64_t dropped = 0;   // windows answered with nothing: overload, shutdown
    std::int64_t rejected = 0;  // STATUS_REJECTED estimates + unattributable messages
    std::int64_t unattributable = 0;  // part of rejected: counted, never answered
    std::int64_t input_damaged = 0;   // damaged stretches of an input log, skipped
    std::int64_t output_errors = 0;   // messages that could not be written or published
    std::int64_t foreign_estimates = 0;  // estimates for this daemon's windows from another publisher
    std::int64_t other_shards = 0;  // windows another shard answers: ignored here (part of received)
  };

  void on_received() { ++totals_.received; }
  void on_dropped(std::int64_t n = 1) { totals_.dropped += n; }
  void on_unattributable() {
    ++totals_.rejected;
    ++totals_.unattributable;
  }
  void on_input_damaged(std::int64_t n = 1) { totals_.input_damaged += n; }
  void on_output_error() { ++totals_.output_errors; }
  void on_foreign_estimate() { ++totals_.foreign_estimates; }
  void on_other_shard() { ++totals_.other_shards; }
  // An estimate was published: latency receive -> publish and the solve time (0 when none).
  void on_done(double latency_us, double solve_us, bool rejected);

  const Totals& totals() const { return totals_; }

  // Receive -> publish over the whole run (every estimate since start), for the line tipforced
  // logs when it stops: the periods' messages hold each period alone, and the last period of a
  // stream that ended before the stop holds nothing. Kept as a histogram with buckets 1 % wide,
  // so a daemon that runs for months holds a fixed ~15 kB: p50 and p99 are the upper edge of the
  // bucket holding that rank (at most 1 % above the nearest-rank value), max is exact.
  struct RunLatency {
    std::int64_t count = 0;
    double p50_us = 0, p99_us = 0, max_us = 0;
  };
  RunLatency run_latency() const;

  // Builds the message for the period that ends now and starts the next period.
  // period_s: the length of the period that ends (for windows_per_s).
  latency_stats_t take_period(std::int64_t utime, const std::string& backend, double period_s, int queue_depth);

 private:
  Totals totals_;
  std::vector<double> latency_us_;  // this period
  std::vector<double> solve_us_;    // this period
  std::int64_t done_in_period_ = 0;
  std::vector<std::int64_t> run_buckets_;  // run_latency's histogram, grown on demand
  std::int64_t run_count_ = 0;
  double run_max_us_ = 0;
};

}  // namespace tipforce::daemon
