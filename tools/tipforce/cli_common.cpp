#include "cli_common.hpp"

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
