#pragma once
// `tipforce simulate --live`: a simulated microscope that obeys setpoint commands (issue 13).
#include <string>

#include "scan_description.hpp"

namespace tipforce::cli {

struct LiveOptions {
  std::string config_path, probe;
  std::string lcm_url;                  // "" = LCM's default
  std::string channel;                  // windows
  std::string estimate_channel;         // lockstep = estimate
  std::string instrument_channel = "TIPFORCE_INSTRUMENT";
  std::string lockstep = "instrument";  // "estimate" (open loop) or "instrument" (closed loop)
  double timeout_s = 30;
  std::string truth_csv;
};

// Publishes the scan's windows one at a time, each after the answer to the one before (lock-step:
// the reference integrator takes about 10 times a window's own duration), applies the setpoints
// of the answers to the following pixels and writes the truth of every pixel to
// options.truth_csv. Exits with CLI::RuntimeError(2) on bad input, (1) when an answer does not
// come within timeout_s or the CSV cannot be written.
void run_live_simulation(const LiveOptions& options, const ProbeModel& probe, const Scan& scan, const ScanTruth& truth);

}  // namespace tipforce::cli
