#pragma once
// One window of measured deflection: one pixel (the library's view of deflection_window_t).
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "tipforce/drive.hpp"

namespace tipforce {

enum class InitialState { rest = 0, continued = 1, unknown = 2 };

inline constexpr int kMaxWindowSamples = 1'000'000;

struct Window {
  InitialState initial = InitialState::rest;
  double t0_s = 0;               // time of the first sample on the drive's clock
  double sample_period_s = 0;
  Drive drive;
  std::vector<double> deflection_m;  // measured signal, one value per sample
  int n_samples() const { return static_cast<int>(deflection_m.size()); }
};

// Why a window cannot be inverted (empty, too long, non-finite samples, bad period, sampled drive
// without one base value per sample, ...), or nullopt if it can.
std::optional<std::string> window_problem(const Window& window);

// A 64-bit hash (FNV-1a) of what the window measured: its start time, sample period, drive and
// samples (not its initial state). The same window has the same identity wherever and whenever it is
// inverted: what seeds a cold start's random search, so that its estimate depends on the window
// and the probe's configuration alone.
std::uint64_t window_identity(const Window& window);

class ModalModel;
class ParameterSpace;

// What a window must satisfy to be inverted for one probe, derived once from its cantilever and
// parameters. A window outside these is physically absurd for the probe (issue 10: a drive
// amplitude of 1e30 m or a frequency of 1 THz passed the plain checks, and the fit it produced
// then spoiled hundreds of good windows after it).
struct WindowLimits {
  int min_samples = 8;        // the unknowns, the start's four nuisance unknowns, and one more
  int max_samples = kMaxWindowSamples;
  double min_sample_period_s = 1e-10;  // 10 GHz sampling: beyond any deflection detector
  double mode1_hz = 0;        // must lie below the sampling's Nyquist frequency
  double max_amplitude_m = 0; // the cantilever's length (a calibrated probe: 1 mm)
  // The drive frequency (the chirp's instantaneous one across the window included) lies between
  // a decade below the first mode and a decade above the highest, and below Nyquist.
  double min_frequency_hz = 0, max_frequency_hz = 0;
  double max_abs_t0_s = 1e7;        // the drive's phase keeps its precision (sin of f t0)
  double max_abs_phase_rad = 1e6;
  // Which drive values come from the window (the others are fixed or estimated: not checked).
  bool amplitude_from_window = true, frequency_from_window = true, phase_from_window = true,
       chirp_from_window = true;
  double length_m = 0;        // for messages; 0 for a calibrated probe
};
WindowLimits window_limits(const ModalModel& modal, double cantilever_length_m, const ParameterSpace& space,
                           int max_samples);

// Why the window is absurd for the probe, or nullopt. Assumes window_problem() found nothing.
std::optional<std::string> window_problem_for_probe(const Window& window, const WindowLimits& limits);

}  // namespace tipforce
