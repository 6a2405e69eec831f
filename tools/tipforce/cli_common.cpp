#include "cli_common.hpp"

#include <CLI/CLI.hpp>

#include "tipforce/event_log.hpp"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <iostream>

namespace tipforce::cli {

Config load_config_or_exit(const std::string& path) {
  try {
    return load_config(path);
  } catch (const ConfigError& e) {
    std::cerr << "tipforce: config error: " << e.what() << "\n";
    std::exit(2);
  }
}

void refuse_output_over_inputs(const std::string& command, const std::string& option, const std::string& out,
                               const std::vector<NamedInput>& inputs) {
  for (const NamedInput& in : inputs) {
    if (in.path.empty() || !lcmio::same_file(in.path, out)) continue;
    std::cerr << "tipforce " << command << ": " << option << " " << out << " is " << in.what << " " << in.path
              << " (the same file); writing there would destroy it\n";
    throw CLI::RuntimeError(2);
  }
}

void Progress::update(std::int64_t done, std::int64_t total) {
  if (!isatty(STDERR_FILENO) || total <= 0) return;
  const std::int64_t percent = done * 100 / total;
  if (percent == last_percent_) return;
  last_percent_ = percent;
  const int width = 40, fill = static_cast<int>(percent * width / 100);
  std::fprintf(stderr, "\r%s [%s%s] %3lld%% (%lld/%lld)", label_.c_str(), std::string(fill, '#').c_str(),
               std::string(width - fill, ' ').c_str(), static_cast<long long>(percent), static_cast<long long>(done),
               static_cast<long long>(total));
  drawn_ = true;
}

void Progress::finish() {
  if (drawn_) std::fprintf(stderr, "\n");
  drawn_ = false;
}

}  // namespace tipforce::cli
