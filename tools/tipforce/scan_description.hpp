#pragma once
// A synthetic scan's description (scan.toml: sampling, drive, truth per pixel), read for
// `tipforce simulate` and its live mode, and what both need of it: the truth's full parameter
// vectors and the steady start.
#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "tipforce/tipforce.hpp"

namespace tipforce::cli {

// The largest scan `tipforce simulate` writes: 4096 x 4096 pixels, and 2^35 samples in all
// (4096 x 4096 windows of 2048 samples, 128 GiB of float deflection). Generous for any real AFM
// scan (a 1 MHz window of 1250 samples at 4096 x 4096 fits); beyond it a typo (1048576 x 1048576
// pixels) would write until the disk is full.
inline constexpr std::int64_t kMaxScanPixels = std::int64_t{4096} * 4096;
inline constexpr std::int64_t kMaxScanSamples = std::int64_t{1} << 35;

struct Scan {
  double sample_period_s = 1e-7;
  int samples_per_window = 4000;
  int pixels_x = 1, pixels_y = 1;
  std::string start = "rest";
  // How each later line's first window is marked: "continued" (the trajectory is one, and says
  // so) or "unknown" (as an acquisition marks the pixel after its retrace: a cold start).
  std::string line_start = "continued";
  double noise_m = 0.0;
  std::uint64_t seed = 1;
  double scan_size_x_m = 0, scan_size_y_m = 0;  // 0: unknown (no scan_geometry_t written)
  Drive drive;
  // parameter -> pixels_y x pixels_x values (row-major)
  std::map<std::string, std::vector<double>> truth;
  std::vector<std::string> truth_files;  // the CSV files the truth was read from
};

// How pixel px's window says it starts: the scan's start for the first, line_start for a later
// line's first, continued otherwise.
InitialState scan_initial_state(const Scan& scan, int px);

// Exits (CLI::RuntimeError 2) with "tipforce simulate: FILE: KEY: problem" on stderr.
Scan read_scan(const std::string& path);

// Exits as read_scan, naming the pixel and the reason, when the probe's readers (tipforced and
// tipforce invert with the same config) would reject the scan's windows: a drive outside a decade
// of the probe's modes, a sampling that cannot resolve mode 1, windows shorter than the probe's
// unknowns need or longer than daemon.max_window_samples, a chirp that sweeps out of range.
void check_scan_windows_for_probe(const Scan& scan, const ProbeModel& probe, const std::string& scan_path);

// The truth of a scan for one probe: the full parameter vector of each pixel.
class ScanTruth {
 public:
  // Exits as read_scan when a model parameter is neither in the truth nor fixed in the config,
  // or a truth entry is not a model parameter.
  ScanTruth(const Scan& scan, const ProbeModel& probe, const std::string& scan_path);
  std::vector<double> full_at(int pixel) const;
  // The model parameters the truth table gives, in model order (the truth CSV's columns).
  const std::vector<std::string>& names() const { return names_; }
  double value(const std::string& name, int pixel) const { return scan_->truth.at(name)[static_cast<std::size_t>(pixel)]; }

 private:
  const Scan* scan_;
  ParameterSpace space_;
  std::vector<double> fixed_full_;
  std::vector<std::string> names_;
};

// The run-in of a scan that starts "steady": six decay times of mode 1, but at most
// kMaxLeadPeriods drive periods (a probe of Q 1e4 needed 19,000 of them and 45 s for 8 windows;
// Q 1e7 overflowed the sample count), sampled at the scan's period or, past kMaxLeadSamples of
// it (1e-10 s sampling hung), coarser.
inline constexpr double kMaxLeadPeriods = 2000;
inline constexpr double kMaxLeadSamples = 1e6;
struct LeadIn {
  double duration_s = 0;
  double sample_period_s = 0;
  std::int64_t samples = 0;
  bool capped = false;  // six decay times would have been longer
};
LeadIn lead_in(const Scan& scan, double mode1_decay_s);

// The state at the first sample of a scan that starts "steady": run in from the drive's linear
// steady state for six decay times of mode 1 with `full` (the first pixel's parameters), by the
// reference integrator; rest otherwise. A chirp runs in as the sine at its frequency at t = 0.
// Says on stderr when the run-in was cut at kMaxLeadPeriods.
ModalState scan_start_state(const Scan& scan, const ProbeModel& probe, const std::vector<double>& full);

}  // namespace tipforce::cli
