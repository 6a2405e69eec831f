#include "latency_stats.hpp"

#include <algorithm>

#include "tipforce/percentile.hpp"

namespace tipforce::daemon {

namespace {
// tipforce::percentile, 0 for a period without values (latency_stats_t's fields are numbers).
double percentile_or_zero(const std::vector<double>& values, double q) {
  return values.empty() ? 0.0 : percentile(values, q);
}
}  // namespace

void LatencyStats::on_done(double latency_us, double solve_us, bool rejected) {
  ++totals_.done;
  ++done_in_period_;
  if (rejected) ++totals_.rejected;
  latency_us_.push_back(std::max(0.0, latency_us));
  // A window rejected before solving has no solve time; it does not pull the solve percentiles down.
  if (solve_us > 0) solve_us_.push_back(solve_us);
}

latency_stats_t LatencyStats::take_period(std::int64_t utime, const std::string& backend, double period_s,
                                          int queue_depth) {
  latency_stats_t m{};
  m.utime = utime;
  m.backend = backend;
  m.period_s = period_s;
  m.windows_received = totals_.received;
  m.windows_done = totals_.done;
  m.windows_dropped = totals_.dropped;
  m.windows_rejected = totals_.rejected;
  m.queue_depth = queue_depth;
  m.latency_p50_us = percentile_or_zero(latency_us_, 0.50);
  m.latency_p90_us = percentile_or_zero(latency_us_, 0.90);
  m.latency_p99_us = percentile_or_zero(latency_us_, 0.99);
  m.latency_max_us = latency_us_.empty() ? 0.0 : *std::max_element(latency_us_.begin(), latency_us_.end());
  m.solve_p50_us = percentile_or_zero(solve_us_, 0.50);
  m.solve_p99_us = percentile_or_zero(solve_us_, 0.99);
  m.windows_per_s = period_s > 0 ? static_cast<double>(done_in_period_) / period_s : 0.0;
  m.input_damaged = totals_.input_damaged;
  m.output_errors = totals_.output_errors;
  m.foreign_estimates = totals_.foreign_estimates;
  m.windows_other_shards = totals_.other_shards;
  // Unsharded unless the daemon says otherwise.
  m.shard_index = 0;
  m.shard_count = 1;
  latency_us_.clear();
  solve_us_.clear();
  done_in_period_ = 0;
  return m;
}

}  // namespace tipforce::daemon
