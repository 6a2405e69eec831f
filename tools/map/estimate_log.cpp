#include "estimate_log.hpp"


#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <fstream>
#include <optional>
#include <system_error>

#include "map_error.hpp"
#include "tipforce/event_log.hpp"

namespace tipforce::map {
namespace {
// Decodes one message; false when the bytes are not a complete message of type T.
template <typename T>
bool decode_exact(const tipforce::lcmio::LogEvent& ev, T& out) {
  if (ev.data.empty()) return false;
  try {
    const int n = out.decode(ev.data.data(), 0, static_cast<int>(ev.data.size()));
    return n >= 0;
  } catch (const std::exception&) {  // e.g. an absurd array length from corrupt bytes
    return false;
  }
}

}  // namespace

LogContents read_estimate_log(const std::string& path, const std::string& estimate_channel,
                              const std::string& stats_channel, const std::string& scan_channel) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) throw MapInputError("cannot read " + path + ": no such file");
  if (std::filesystem::is_directory(path, ec)) throw MapInputError("cannot read " + path + ": it is a directory");
  // Before it is opened: opening a FIFO waits for a writer, and `tipforce map --in FIFO` hung.
  if (!std::filesystem::is_regular_file(path, ec))
    throw MapInputError("cannot read " + path + ": not a regular file (a FIFO or device is no LCM log)");
  std::optional<tipforce::lcmio::LogReader> log;
  try {
    log.emplace(path);
  } catch (const tipforce::lcmio::LogError& e) {
    // Unreadable (permissions) or not a regular file: the file given is at fault, as tipforce
    // invert says of its --in.
    throw MapInputError(std::string("cannot open LCM log: ") + e.what());
  }

  LogContents out;
  while (true) {
    std::optional<tipforce::lcmio::LogEvent> ev = log->next();
    for (const auto& d : log->take_damage())
      out.damage.push_back(tipforce::lcmio::describe(d));
    if (!ev) break;
    ++out.events;
    if (ev->channel == estimate_channel) {
      tipforce::force_estimate_t msg;
      if (decode_exact(*ev, msg))
        out.estimates.push_back(std::move(msg));
      else
        ++out.undecodable_estimates;
    } else if (ev->channel == stats_channel) {
      tipforce::latency_stats_t msg;
      if (decode_exact(*ev, msg))
        out.stats.push_back(std::move(msg));
      else
        ++out.undecodable_stats;
    } else if (ev->channel == scan_channel) {
      tipforce::scan_geometry_t msg;
      if (decode_exact(*ev, msg))
        out.scans.push_back(std::move(msg));
      else
        ++out.other_channels[ev->channel + " (undecodable)"];
    } else {
      ++out.other_channels[ev->channel];
    }
  }
  out.damaged_stretches = static_cast<std::size_t>(log->damaged_stretches());
  // A read error is the machine's (exit 1); what the file holds is the user's to fix (exit 2),
  // unless it is a log damaged from its start (exit 3).
  if (!log->error().empty()) throw MapError(log->error());
  if (out.events == 0) {
    const std::uintmax_t bytes = std::filesystem::file_size(path, ec);
    if (!ec && bytes == 0) throw MapInputError(path + " is empty (0 bytes): there is no LCM event to map");
    const std::string size = std::to_string(bytes) + " bytes";
    if (out.damage.empty() || !tipforce::lcmio::starts_with_sync_word(path)) {
      char sync[16];
      std::snprintf(sync, sizeof sync, "0x%08X", static_cast<unsigned>(tipforce::lcmio::kLogSyncWord));
      throw MapInputError(path + " is not an LCM log: its " + size +
                          " hold no LCM event, and it does not start with LCM's sync word (" + sync + ")");
    }
    std::vector<std::string> damage;
    for (const auto& line : out.damage) damage.push_back(path + ": " + line);
    throw MapDamagedError(path + " is an LCM log damaged from its first event on (cut short inside it?): none of its " +
                              size + " could be read as an event",
                          std::move(damage));
  }
  return out;
}
}  // namespace tipforce::map

namespace tipforce::map {
LogContents read_estimate_logs(const std::vector<std::string>& paths, const std::string& estimate_channel,
                               const std::string& stats_channel, const std::string& scan_channel,
                               std::vector<std::string>& notes) {
  if (paths.size() == 1) return read_estimate_log(paths.front(), estimate_channel, stats_channel, scan_channel);
  LogContents all;
  std::vector<std::string> empty;
  for (const std::string& path : paths) {
    std::error_code ec;
    if (std::filesystem::is_regular_file(path, ec) && std::filesystem::file_size(path, ec) == 0 && !ec) {
      empty.push_back(path);
      continue;
    }
    LogContents one;
    try {
      one = read_estimate_log(path, estimate_channel, stats_channel, scan_channel);
    } catch (const MapDamagedError& e) {
      // A shard's log damaged from its start is damage within the whole, as a damaged stretch
      // inside a log is: the other shards are mapped and the command exits 3.
      all.damaged_stretches += e.damage().size();
      all.damage.insert(all.damage.end(), e.damage().begin(), e.damage().end());  // they name their file
      continue;
    }
    all.events += one.events;
    all.undecodable_estimates += one.undecodable_estimates;
    all.undecodable_stats += one.undecodable_stats;
    all.damaged_stretches += one.damaged_stretches;
    for (auto& e : one.estimates) all.estimates.push_back(std::move(e));
    for (auto& s : one.stats) all.stats.push_back(std::move(s));
    for (auto& g : one.scans) all.scans.push_back(std::move(g));
    for (const auto& [channel, n] : one.other_channels) all.other_channels[channel] += n;
    for (const auto& line : one.damage) all.damage.push_back(path + ": " + line);
  }
  std::stable_sort(all.estimates.begin(), all.estimates.end(), [](const auto& a, const auto& b) {
    return a.probe != b.probe ? a.probe < b.probe : a.seq < b.seq;
  });
  if (empty.size() == paths.size())
    throw MapInputError("all " + std::to_string(paths.size()) + " input logs are empty (" + paths.front() + ", ...)");
  notes.push_back("read " + std::to_string(paths.size() - empty.size()) + " logs as one (" + paths.front() +
                  (paths.size() > 1 ? ", ..." : "") + ")");
  for (const auto& path : empty) notes.push_back(path + " is empty (a shard with no windows?): skipped");
  return all;
}
}  // namespace tipforce::map
