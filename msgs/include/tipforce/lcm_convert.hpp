#pragma once
// The boundary between LCM messages and the library: decoding and validating windows, and
// building estimates. The tipforce command and tipforced both go through here.
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>

#include "tipforce/deflection_window_t.hpp"
#include "tipforce/force_estimate_t.hpp"
#include "tipforce/inversion.hpp"
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
  Window window;  // valid only when error is empty
  // Why the window cannot be inverted; empty when it can.
  std::string error;
  // False when not even the header could be read (random bytes, wrong type): such a window can
  // only be counted, not answered.
  bool attributable = false;
};

// Decodes raw bytes received on the window channel and validates them (fingerprint, n_samples,
// finite samples, sample period, size limit). Never throws.
DecodedWindow decode_window(const void* data, std::size_t size);

// The library window to a message (used by `tipforce simulate`).
deflection_window_t to_message(const WindowHeader& header, const Window& window);

force_estimate_t to_message(const WindowHeader& header, std::string_view model, const Estimate& estimate,
                            int64_t receive_utime, int64_t publish_utime);
force_estimate_t rejected_estimate(const WindowHeader& header, std::string_view model, const std::string& why,
                                   int64_t receive_utime, int64_t publish_utime);

int64_t now_utime();

}  // namespace tipforce::lcmio
