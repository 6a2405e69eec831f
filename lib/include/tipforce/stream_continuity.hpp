#pragma once
// How a window of a probe's stream starts: the one place that decides whether a window marked
// CONTINUED continues the last fit, coasts the last fit across a gap first, or starts cold
// (issue 9: this used to be decided in WindowProcessor, as a side effect inside an `if`, and again
// in the inverter). The Inverter asks it once per window; it only decides, the Inverter acts. (A
// CONTINUED window that the latency budget left unfitted becomes a gap for the window after it:
// the Inverter coasts the last fit across it, and the next window's seq then follows that.)
#include <cstdint>
#include <optional>

#include "tipforce/window.hpp"

namespace tipforce {

// Where a window stands in its probe's stream, from its sequence number.
enum class StreamStep {
  follows,  // the next seq after the last window inverted (or no seq: the caller says it follows)
  gap,      // seq jumped ahead: the windows in between were dropped, lost or rejected
  broken,   // the first window seen, or a seq not after the last one (a restart, a replay)
};
StreamStep stream_step(std::optional<std::int64_t> last_seq, std::optional<std::int64_t> seq);

enum class StartChoice {
  rest,                 // as the window says: from rest
  continue_fit,         // from the last fit's end state
  coast_then_continue,  // the last fit's end state advanced across the gap, then as continue_fit
  cold,                 // start unknown: estimated from the window alone
};

// asked: the window's initial state. have_fit: there is a fitted end state to continue from (a
// fit that was not trusted leaves none). coastable: that end state can be advanced to the
// window's start (same sample period, on its sample grid, a gap not too long: Inverter::coast_to).
//   REST -> rest; UNKNOWN -> cold.
//   CONTINUED -> continue_fit when it follows a fit; across a gap, coast_then_continue when the
//   fit is coastable; cold otherwise (no fit, the stream broken, a gap that cannot be coasted).
StartChoice decide_start(InitialState asked, StreamStep step, bool have_fit, bool coastable);

}  // namespace tipforce
