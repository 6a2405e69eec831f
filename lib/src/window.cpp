#include "tipforce/window.hpp"

#include <cmath>

namespace tipforce {

std::optional<std::string> window_problem(const Window& w) {
  const int n = w.n_samples();
  if (n <= 0) return "window has no samples";
  if (n > kMaxWindowSamples)
    return "window has " + std::to_string(n) + " samples, more than the limit of " + std::to_string(kMaxWindowSamples);
  if (!std::isfinite(w.sample_period_s) || w.sample_period_s <= 0)
    return "sample_period_s must be positive and finite, got " + std::to_string(w.sample_period_s);
  if (!std::isfinite(w.t0_s)) return "t0_s is not finite";
  for (int i = 0; i < n; ++i)
    if (!std::isfinite(w.deflection_m[static_cast<std::size_t>(i)]))
      return "deflection sample " + std::to_string(i) + " is not finite";
  const Drive& d = w.drive;
  if (!std::isfinite(d.amplitude_m) || !std::isfinite(d.frequency_hz) || !std::isfinite(d.phase_rad) ||
      !std::isfinite(d.chirp_hz_per_s))
    return "drive parameters must be finite";
  if (d.kind == DriveKind::sampled) {
    if (static_cast<int>(d.base_m.size()) != n)
      return "sampled drive needs one base sample per deflection sample (" + std::to_string(d.base_m.size()) +
             " for " + std::to_string(n) + ")";
    for (double y : d.base_m)
      if (!std::isfinite(y)) return "base sample is not finite";
    if (n < 3) return "sampled drive needs at least 3 samples";
  }
  return std::nullopt;
}

}  // namespace tipforce
