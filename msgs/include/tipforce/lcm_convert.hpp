#pragma once
// The boundary between LCM messages and the library: decoding and validating windows, and
// building estimates. The tipforce command and tipforced both go through here.
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

#include "tipforce/deflection_window_t.hpp"
#include "tipforce/force_estimate_t.hpp"
#include "tipforce/inversion.hpp"
#include "tipforce/shard.hpp"
#include "tipforce/window.hpp"

namespace tipforce::lcmio {

// Who a window belongs to: enough to answer it.
struct WindowHeader {
  int64_t utime = 0;
  std::string probe;
  int64_t seq = 0;
  int32_t pixel_x = 0;
  int32_t pixel_y = 0;
};

struct DecodedWindow {
  WindowHeader header;
  Window window;  // decoded only when error is empty (and not yet validated: window_problem)
  // Why the window cannot be inverted; empty when it can.
  std::string error;
  // False when not even the header could be read (random bytes, wrong type): such a window can
  // only be counted, not answered.
  bool attributable = false;
};

// Probe names: at most this many bytes, printable ASCII (no control characters, no NUL). A name
// that comes into the log lines and the estimates must not be able to forge a log line or fill
// the disk.
inline constexpr std::size_t kMaxProbeNameBytes = 64;
// Why `name` is not an acceptable probe name, or nullopt.
std::optional<std::string> probe_name_problem(std::string_view name);
// `raw` made printable for a log line or an estimate: control and non-ASCII bytes as \xNN, at
// most max_bytes of the input, and how many more there were.
std::string escape_for_log(std::string_view raw, std::size_t max_bytes = kMaxProbeNameBytes);

// Decodes raw bytes received on the window channel: the wire format is checked (fingerprint,
// header, array lengths before anything is allocated, n_samples and its limit, the enums, the
// probe name). What the samples say is not: the Inverter validates the window, once
// (window_problem and window_problem_for_probe; code that decodes a window to use it otherwise
// calls those). A window whose probe name is refused is answered under the escaped name. Never
// throws.
DecodedWindow decode_window(const void* data, std::size_t size);

// Only the header, cheaply (no arrays are read or allocated): who answers the window, and under
// which name. The probe is the name as answered: a refused name (probe_name_problem) in its
// escaped form, as decode_window gives it. nullopt when the bytes are not a window or the header
// cannot be read. The daemon's IO thread uses it to decide a window's shard before queueing it.
std::optional<WindowHeader> decode_window_header(const void* data, std::size_t size);
// The same five fields of a force_estimate_t (the messages begin alike), without reading its
// arrays: what an estimate seen on the estimate channel answers. nullopt when not an estimate.
std::optional<WindowHeader> decode_estimate_header(const void* data, std::size_t size);

// The shard that answers these bytes from the window channel: ShardSpec::shard_of on the header.
// Bytes without a readable header (garbage: counted, never answered) belong to shard 0, so that
// every message on the channel is counted by exactly one shard. tipforced and `tipforce invert
// --shard` both decide through this.
int window_shard(const void* data, std::size_t size, const ShardSpec& spec);

// The library window to a message (used by `tipforce simulate`).
deflection_window_t to_message(const WindowHeader& header, const Window& window);

force_estimate_t to_message(const WindowHeader& header, std::string_view model, const Estimate& estimate,
                            int64_t receive_utime, int64_t publish_utime);
force_estimate_t rejected_estimate(const WindowHeader& header, std::string_view model, const std::string& why,
                                   int64_t receive_utime, int64_t publish_utime);

int64_t now_utime();

}  // namespace tipforce::lcmio
