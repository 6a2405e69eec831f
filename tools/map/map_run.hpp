#pragma once
#include <cstddef>
#include <map>
#include <optional>
#include <ostream>
#include <string>
#include <utility>
#include <vector>

#include "latency_plot.hpp"
#include "map_image.hpp"
#include "truth.hpp"

namespace tipforce::map {
struct MapOptions {
  std::string in;                                 // estimates LCM log
  std::vector<std::string> more_in;               // further estimate logs read with it as one (shards)
  std::string out;                                // output directory (created)
  std::string probe;                              // "" = the only probe in the log
  std::string truth;                              // "" = no truth comparison
  std::string channel = "TIPFORCE_ESTIMATE";
  std::string stats_channel = "TIPFORCE_STATS";
  std::string scan_channel = "TIPFORCE_SCAN";     // scan_geometry_t (tipforce import)
  // The scan size, first found of: scan_size_*_m, pixel_size_m x pixels, a scan_geometry_t of the
  // probe in the estimates log, one in scan_log (e.g. the windows log that tipforced inverted).
  // None: the axes count pixels and the .gsf files say the size is unknown.
  double scan_size_x_m = 0, scan_size_y_m = 0;
  double pixel_size_m = 0;
  std::string scan_log;
};

struct MapReport {
  std::string probe;
  std::size_t estimates = 0;                      // of the selected probe
  std::map<int, std::size_t> per_status;          // status code -> count
  std::size_t stats_messages = 0;
  std::size_t undecodable_estimates = 0, undecodable_stats = 0;
  std::size_t damaged_stretches = 0;              // damaged parts of the log skipped
  std::vector<std::string> damage;                // where and why, one line each ("skipped N damaged bytes at offset ...")
  int width = 0, height = 0;                      // the estimates' extent, or the scan's where larger
  std::vector<std::pair<int, int>> missing, rejected;
  std::vector<MapImageInfo> images;               // every quantity map, then status
  std::vector<std::string> files;                 // every file written
  std::optional<LatencySummary> latency;
  std::vector<ParamAccuracy> accuracy;
  std::vector<std::string> notes;
  ScanSize scan;                                  // what the axes used (unknown: 0)
  std::string scan_source;                        // where the size came from
  bool dissipation_mapped = true;                 // false when no model of the log dissipates
};

// The whole `tipforce map` run; prints its summary on `out`. Throws, naming the file, and before
// anything is written unless said: MapInputError for bad input (a missing, empty or non-LCM log,
// one without estimates of the probe, a bad option value or truth file), MapDamagedError for a log
// so damaged that no estimate could be read, MapError for what is not the input's fault (a read
// error, an output directory that cannot be made or written: possibly after some files). A damaged
// log with estimates is read around and mapped; the report counts and lists the damage (the
// command exits 3 for it).
MapReport run_map(const MapOptions& opt, std::ostream& out);
}  // namespace tipforce::map
