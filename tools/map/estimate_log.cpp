#include "estimate_log.hpp"

#include <lcm/lcm-cpp.hpp>

#include <exception>
#include <filesystem>
#include <system_error>

#include "map_error.hpp"

namespace tipforce::map {
namespace {
// Decodes one message; false when the bytes are not a complete message of type T.
template <typename T>
bool decode_exact(const lcm::LogEvent& ev, T& out) {
  if (ev.data == nullptr || ev.datalen <= 0) return false;
  try {
    const int n = out.decode(ev.data, 0, ev.datalen);
    return n >= 0;
  } catch (const std::exception&) {  // e.g. an absurd array length from corrupt bytes
    return false;
  }
}
}  // namespace

LogContents read_estimate_log(const std::string& path, const std::string& estimate_channel,
                              const std::string& stats_channel) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) throw MapError("cannot read " + path + ": no such file");
  if (std::filesystem::is_directory(path, ec)) throw MapError("cannot read " + path + ": it is a directory");
  lcm::LogFile log(path, "r");
  if (!log.good()) throw MapError("cannot open LCM log " + path);

  LogContents out;
  for (const lcm::LogEvent* ev = log.readNextEvent(); ev != nullptr; ev = log.readNextEvent()) {
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
    } else {
      ++out.other_channels[ev->channel];
    }
  }
  if (out.events == 0)
    throw MapError(path + " holds no LCM events (empty, truncated or not an LCM log)");
  return out;
}
}  // namespace tipforce::map
