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

// A file a command reads, named as its option or role says ("the config", "--scan").
struct NamedInput {
  std::string what;
  std::string path;
};

// Exits 2 with "tipforce COMMAND: OPTION OUT is WHAT PATH (the same file); ..." on stderr when the
// output `out` is one of the inputs as a file (device and inode, or the resolved path, so links and
// ./ paths are caught). Call it before anything is opened for writing: opening truncates, and
// `--out c.toml` destroyed the config that the next command then failed to read.
void refuse_output_over_inputs(const std::string& command, const std::string& option, const std::string& out,
                               const std::vector<NamedInput>& inputs);

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
