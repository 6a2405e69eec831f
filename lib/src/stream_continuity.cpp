#include "tipforce/stream_continuity.hpp"

namespace tipforce {

StreamStep stream_step(std::optional<std::int64_t> last_seq, std::optional<std::int64_t> seq) {
  if (!seq) return StreamStep::follows;
  if (!last_seq || *seq <= *last_seq) return StreamStep::broken;
  return *seq == *last_seq + 1 ? StreamStep::follows : StreamStep::gap;
}

StartChoice decide_start(InitialState asked, StreamStep step, bool have_fit, bool coastable) {
  switch (asked) {
    case InitialState::rest: return StartChoice::rest;
    case InitialState::unknown: return StartChoice::cold;
    case InitialState::continued: break;
  }
  if (!have_fit) return StartChoice::cold;
  switch (step) {
    case StreamStep::follows: return StartChoice::continue_fit;
    case StreamStep::gap: return coastable ? StartChoice::coast_then_continue : StartChoice::cold;
    case StreamStep::broken: break;
  }
  return StartChoice::cold;
}

}  // namespace tipforce
