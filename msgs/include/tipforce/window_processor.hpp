#pragma once
// Turns raw window messages into estimates: decode, validate, pick the probe's Inverter, invert.
// `tipforce invert` and tipforced both answer windows through this one class, so their estimates
// are the same for the same log.
#include <cstddef>
#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <string>

#include "tipforce/config.hpp"
#include "tipforce/force_estimate_t.hpp"
#include "tipforce/forward.hpp"
#include "tipforce/inversion.hpp"
#include "tipforce/lcm_convert.hpp"
#include "tipforce/setpoint_advisor.hpp"
#include "tipforce/setpoint_command_t.hpp"

namespace tipforce::lcmio {

struct ProcessedWindow {
  // The estimate to publish; nullopt when the bytes could not even be attributed to a window
  // (random bytes, another message type): such input is counted, not answered.
  std::optional<force_estimate_t> estimate;
  bool rejected = false;   // decoded badly or invalid: STATUS_REJECTED (or unattributable)
  std::string reason;      // for the log line, when rejected
  double solve_seconds = 0;  // the inverter's timing of the solve (0 when none ran)
};

class WindowProcessor {
 public:
  // Builds one Inverter per configured probe, prepared for the probe's prepare_sample_periods_s
  // (the first window is then answered as fast as the rest). Throws ConfigError for a probe whose
  // model cannot be built.
  WindowProcessor(const Config& config, ForwardBackend& backend);

  // Never throws for bad input. A window is REJECTED (with the reason, without touching the
  // probe's stream state) when it cannot be decoded, names an unknown probe, or cannot be
  // inverted: malformed or physically absurd for its probe (the Inverter's one validation:
  // window_problem, window_problem_for_probe). receive_utime is stamped
  // into the estimate; publish_utime is set to the time the call returns (the caller may
  // overwrite it when it actually publishes).
  // The probe's latency budget (deadline_ms) counts from budget_start_utime, receive_utime when
  // not given (a daemon reading a log file ahead of the solver gives the time it takes the
  // window from its queue: that wait is its own doing, not the acquisition's); from the call
  // when that is 0 (not known).
  ProcessedWindow process(const void* data, std::size_t size, int64_t receive_utime,
                          std::optional<int64_t> budget_start_utime = std::nullopt);

  // For a probe with a [probe.NAME.advisor] table (issue 13): the setpoint command that answers the
  // window process() answered last, predicted from its fit (msgs/window_advice.cpp). Call it
  // right after process(): it uses the inverter's state. nullopt for a probe without an advisor
  // and for input that got no estimate. Apart from process() so that the estimate can go out
  // before the advisor's forward solves.
  std::optional<setpoint_command_t> advise_last();

 private:
  // One per configured probe: its inverter carries its stream (the previous fit, the last seq).
  struct Probe {
    std::unique_ptr<Inverter> inverter;
    std::optional<SetpointAdvisor> advisor;
    AdvisorOptions advisor_options;
  };
  // The last answered window of a probe with an advisor, until advise_last() takes it.
  struct LastAnswer {
    Probe* probe = nullptr;
    WindowHeader header;
    Window window;
    Estimate estimate;
  };
  void remember(Probe& probe, const WindowHeader& header, Window window, Estimate estimate);
  std::optional<LastAnswer> last_;
  std::map<std::string, Probe> probes_;
};

}  // namespace tipforce::lcmio
