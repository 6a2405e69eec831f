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

}  // namespace tipforce
