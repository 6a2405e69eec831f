#pragma once
#include <cstddef>
#include <optional>
#include <string>
#include <vector>

#include <tipforce/force_estimate_t.hpp>
#include <tipforce/latency_stats_t.hpp>

namespace tipforce::map {
struct LatencySummary {
  std::size_t n = 0;  // estimates with both receive_utime and publish_utime set
  double min_us = 0, p50_us = 0, p90_us = 0, p99_us = 0, max_us = 0;
  std::size_t negative = 0;  // publish before receive (clock trouble), still plotted
};

// Latencies publish_utime - receive_utime of the estimates that carry both times.
std::optional<LatencySummary> summarize_latency(const std::vector<tipforce::force_estimate_t>& estimates);

// Histogram of the receive -> publish latency (us). Throws MapError when it cannot write.
void write_latency_histogram(const std::string& path, const std::vector<tipforce::force_estimate_t>& estimates,
                             const LatencySummary& summary);

// Latency per estimate against receive time since the first (s), with the p50 / p99 series of
// the latency_stats_t messages when there are any.
void write_latency_over_time(const std::string& path, const std::vector<tipforce::force_estimate_t>& estimates,
                             const std::vector<tipforce::latency_stats_t>& stats);

}  // namespace tipforce::map
