#pragma once
// Pieces the subcommands share: loading the config with a clear error, LCM log helpers, stats.
#include <cstdint>
#include <string>
#include <vector>

#include "tipforce/config.hpp"
#include "tipforce/percentile.hpp"

namespace tipforce::cli {

// Exits with status 2 and the ConfigError's text (file: key: problem) on stderr.
Config load_config_or_exit(const std::string& path);

// A one-line progress bar on stderr when it is a terminal.
class Progress {
 public:
  explicit Progress(std::string label) : label_(std::move(label)) {}
  void update(std::int64_t done, std::int64_t total);
  void finish();

 private:
  std::string label_;
  std::int64_t last_percent_ = -1;
  bool drawn_ = false;
};

}  // namespace tipforce::cli
