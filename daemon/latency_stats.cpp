#include "latency_stats.hpp"

#include <algorithm>
#include <cmath>

#include "tipforce/percentile.hpp"

namespace tipforce::daemon {

namespace {
// tipforce::percentile, 0 for a period without values (latency_stats_t's fields are numbers).
double percentile_or_zero(const std::vector<double>& values, double q) {
  return values.empty() ? 0.0 : percentile(values, q);
}

// The run's histogram: bucket 0 holds [0, 1 us], bucket b > 0 holds (1.01^(b-1), 1.01^b] us, up to
// about 100 s (1852 buckets); anything longer lands in the last, whose edge is then the exact max.
constexpr double kBucketRatio = 1.01;
constexpr std::size_t kBuckets = 1853;
std::size_t bucket_of(double latency_us) {
  if (!(latency_us > 1.0)) return 0;
  const double b = std::ceil(std::log(latency_us) / std::log(kBucketRatio));
  return b >= static_cast<double>(kBuckets - 1) ? kBuckets - 1 : static_cast<std::size_t>(b);
}
double bucket_upper_us(std::size_t b) { return std::pow(kBucketRatio, static_cast<double>(b)); }
}  // namespace

void LatencyStats::on_done(double latency_us, double solve_us, bool rejected) {
  ++totals_.done;
  ++done_in_period_;
  if (rejected) ++totals_.rejected;
  latency_us_.push_back(std::max(0.0, latency_us));
  const std::size_t b = bucket_of(latency_us_.back());
  if (run_buckets_.size() <= b) run_buckets_.resize(b + 1, 0);
  ++run_buckets_[b];
  ++run_count_;
  run_max_us_ = std::max(run_max_us_, latency_us_.back());
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

LatencyStats::RunLatency LatencyStats::run_latency() const {
  RunLatency r;
  r.count = run_count_;
  r.max_us = run_max_us_;
  if (run_count_ == 0) return r;
  // Nearest rank, as tipforce::percentile: the bucket where the count reaches ceil(q n).
  const auto at = [&](double q) {
    const auto rank = std::max<std::int64_t>(1, static_cast<std::int64_t>(std::ceil(q * static_cast<double>(run_count_))));
    std::int64_t seen = 0;
    for (std::size_t b = 0; b < run_buckets_.size(); ++b) {
      seen += run_buckets_[b];
      if (seen >= rank) return std::min(bucket_upper_us(b), run_max_us_);
    }
    return run_max_us_;
  };
  r.p50_us = at(0.50);
  r.p99_us = at(0.99);
  return r;
}

}  // namespace tipforce::daemon
