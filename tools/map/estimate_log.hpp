#pragma once
#include <cstddef>
#include <map>
#include <string>
#include <vector>

#include <tipforce/force_estimate_t.hpp>
#include <tipforce/latency_stats_t.hpp>
#include <tipforce/scan_geometry_t.hpp>

namespace tipforce::map {
// Everything `tipforce map` takes from an LCM log.
struct LogContents {
  std::vector<tipforce::force_estimate_t> estimates;  // in log order
  std::vector<tipforce::latency_stats_t> stats;
  std::vector<tipforce::scan_geometry_t> scans;  // on the scan channel (tipforce import), in log order
  std::size_t events = 0;                  // all events read
  std::size_t undecodable_estimates = 0;   // on the estimate channel but not a force_estimate_t
  std::size_t undecodable_stats = 0;
  std::map<std::string, std::size_t> other_channels;  // skipped channels and their event counts
  std::size_t damaged_stretches = 0;       // damaged parts of the log skipped (the rest is read)
  std::vector<std::string> damage;         // where and why, one line each
};

// Reads the log with lcmio::LogReader, which skips a damaged event instead of stopping there (LCM's
// own reader took one for the end of the log). Throws, naming the file: MapInputError when it is
// missing, unreadable, empty or not an LCM log; MapDamagedError when it starts as one but no event
// of it is intact; MapError on a read error. Undecodable messages and damaged stretches are counted.
LogContents read_estimate_log(const std::string& path, const std::string& estimate_channel,
                              const std::string& stats_channel, const std::string& scan_channel = "TIPFORCE_SCAN");
}  // namespace tipforce::map

namespace tipforce::map {
// Several logs read as one: the estimate logs of the shards of one scan (tipforced with
// daemon.shard, `tipforce invert --shard`). Estimates ordered by probe and seq (stably), as one
// run over the whole scan writes them, so that estimates.csv comes out the same; stats in the
// order of the files; counts added up; damage lines naming their file. A 0-byte file (a shard whose share held no window) is
// skipped with a line in `notes`; anything else is read as read_estimate_log reads one log, and
// if every file is empty that is a MapInputError.
LogContents read_estimate_logs(const std::vector<std::string>& paths, const std::string& estimate_channel,
                               const std::string& stats_channel, const std::string& scan_channel,
                               std::vector<std::string>& notes);
}  // namespace tipforce::map
