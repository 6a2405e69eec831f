#pragma once
// The TOML configuration (SPEC section 4). Every problem is reported as "FILE: KEY: PROBLEM".
#include <filesystem>
#include <map>
#include <stdexcept>
#include <string>

#include "tipforce/inversion.hpp"

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
  double stats_period_s = 1.0;
  int queue_capacity = 64;
  std::string backend = "auto";
};

struct ProbeConfig {
  ProbeSpec spec;
  ParameterSpace space;
  InversionOptions options;
};

struct Config {
  std::string source;  // file path, for messages
  DaemonSettings daemon;
  std::map<std::string, ProbeConfig> probes;

  // Throws ConfigError naming the probe if it is not configured.
  ProbeModel probe_model(const std::string& name) const;
};

Config load_config(const std::filesystem::path& path);                // throws ConfigError
Config parse_config(const std::string& toml_text, const std::string& source_name);  // throws ConfigError

}  // namespace tipforce
