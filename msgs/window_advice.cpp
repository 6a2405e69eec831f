// WindowProcessor's advice step (issue 13): the setpoint command for the window it answered last.
#include "tipforce/setpoint_convert.hpp"
#include "tipforce/window_processor.hpp"

#include <exception>

namespace tipforce::lcmio {

std::optional<setpoint_command_t> WindowProcessor::advise_last() {
  if (!last_) return std::nullopt;
  LastAnswer last = std::move(*last_);
  last_.reset();
  Inverter& inverter = *last.probe->inverter;
  FittedWindow fit;
  fit.window = &last.window;
  fit.estimate = &last.estimate;
  fit.end_state = inverter.last_end_state();
  fit.end_t_s = inverter.last_end_t_s();
  fit.full_params = inverter.last_full_params();
  Advice advice;
  try {
    advice = last.probe->advisor->advise(fit, inverter.backend());
  } catch (const std::exception& e) {
    // The advisor answers what it cannot use with no_advice; an exception is a bug, but the
    // command still goes out, saying so.
    advice = Advice{};
    advice.reason = std::string("internal error: ") + e.what();
  }
  return to_command(last.header, advice, last.probe->advisor_options, now_utime());
}

}  // namespace tipforce::lcmio
