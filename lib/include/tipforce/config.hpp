#pragma once
// The TOML configuration (SPEC section 4). Every problem is reported as "FILE: KEY: PROBLEM".
#include <filesystem>
#include <map>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>

#include "tipforce/inversion.hpp"
#include "tipforce/setpoint_advisor.hpp"
#include "tipforce/shard.hpp"
#include "tipforce/window.hpp"

namespace tipforce {

class ConfigError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct DaemonSettings {
  std::string input_url;
  std::string output_url;
  std::string window_channel = "TIPFORCE_WINDOW";
  std::string estimate_channel = "TIPFORCE_ESTIMATE";
  std::string stats_channel = "TIPFORCE_STATS";
  // The setpoint advisor's commands (issue 13), for the probes that have an advisor table.
  std::string setpoint_channel = "TIPFORCE_SETPOINT";
  double stats_period_s = 1.0;
  int queue_capacity = 64;
  std::string backend = "auto";
  // Threads of the CPU backend; 0 = one per core. Several shards on one host each take a share
  // of the cores (issue 12), e.g. 1 for two shards on two cores.
  int cpu_threads = 0;
  // Longer windows are REJECTED: a bound on one window's memory and solve time (a 1,000,000-sample
  // window takes about 100 s and 1 GB on the CPU). At most kMaxWindowSamples (SPEC's limit).
  int max_window_samples = 100'000;
  // Which windows this daemon answers (issue 12): `shard = { index, count, by }`. The default, one
  // shard, answers every window.
  ShardSpec shard;
};

struct ProbeConfig {
  ProbeSpec spec;
  ParameterSpace space;
  InversionOptions options;
  // [probe.NAME.advisor] (issue 13): present when tipforced advises setpoints for this probe.
  std::optional<AdvisorOptions> advisor;
};

struct Config {
  std::string source;  // file path, for messages
  DaemonSettings daemon;
  std::map<std::string, ProbeConfig> probes;

  // Throws ConfigError naming the probe if it is not configured.
  ProbeModel probe_model(const std::string& name) const;
};

// A configuration is a few KiB; a larger file is refused unread (e.g. --config /dev/zero).
inline constexpr std::size_t kMaxConfigBytes = 1 << 20;

// The values a configuration accepts, for other readers of the same quantities (a scan
// description's truth and drive): one set of limits. `what` says the range in words.
struct ValueRange {
  double low, high;
  const char* what;
  bool holds(double v) const { return v >= low && v <= high; }  // false for NaN
};
ValueRange parameter_value_range(std::string_view name);  // a model or drive parameter (SPEC section 1 names)
ValueRange sample_period_range();

Config load_config(const std::filesystem::path& path);                // throws ConfigError
Config parse_config(const std::string& toml_text, const std::string& source_name);  // throws ConfigError

}  // namespace tipforce
