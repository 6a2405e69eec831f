#include "estimate_log.hpp"


#include <exception>
#include <optional>
#include <filesystem>
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
  if (!std::filesystem::exists(path, ec)) throw MapError("cannot read " + path + ": no such file");
  if (std::filesystem::is_directory(path, ec)) throw MapError("cannot read " + path + ": it is a directory");
  std::optional<tipforce::lcmio::LogReader> log;
  try {
    log.emplace(path);
  } catch (const tipforce::lcmio::LogError& e) {
    throw MapError(std::string("cannot open LCM log: ") + e.what());
  }

  LogContents out;
  while (true) {
    std::optional<tipforce::lcmio::LogEvent> ev = log->next();
    for (const auto& d : log->take_damage())
      out.damage.push_back("skipped " + std::to_string(d.bytes) + " damaged bytes at offset " +
                           std::to_string(d.offset) + " (" + d.why + ")");
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
  if (!log->error().empty()) throw MapError(log->error());
  if (out.events == 0)
    throw MapError(path + " holds no LCM events (empty, truncated or not an LCM log)");
  return out;
}
}  // namespace tipforce::map
