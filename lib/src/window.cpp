#include "tipforce/window.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>

#include "tipforce/cantilever.hpp"
#include "tipforce/parameters.hpp"

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

namespace {

class Fnv1a64 {
 public:
  template <typename T>
  void add(const T& value) {
    const auto* bytes = reinterpret_cast<const unsigned char*>(&value);
    for (std::size_t i = 0; i < sizeof(T); ++i) hash_ = (hash_ ^ bytes[i]) * 0x100000001b3ull;
  }
  std::uint64_t value() const { return hash_; }

 private:
  std::uint64_t hash_ = 0xcbf29ce484222325ull;
};

}  // namespace

std::uint64_t window_identity(const Window& w) {
  // Not the initial state: a window inverted as a cold start (marked UNKNOWN, or CONTINUED but
  // found not to continue) is the same window either way.
  Fnv1a64 h;
  h.add(w.t0_s);
  h.add(w.sample_period_s);
  h.add(static_cast<int>(w.drive.kind));
  for (double v : {w.drive.amplitude_m, w.drive.frequency_hz, w.drive.phase_rad, w.drive.chirp_hz_per_s}) h.add(v);
  h.add(w.drive.base_m.size());
  for (double y : w.drive.base_m) h.add(y);
  h.add(w.deflection_m.size());
  for (double u : w.deflection_m) h.add(u);
  return h.value();
}

namespace {
std::string num(double v) {
  std::ostringstream o;
  o.precision(4);
  o << v;
  return o.str();
}
// A calibrated probe gives no length; 1 mm is longer than any AFM cantilever.
constexpr double kCalibratedProbeMaxAmplitudeM = 1e-3;
}  // namespace

WindowLimits window_limits(const ModalModel& modal, double cantilever_length_m, const ParameterSpace& space,
                           int max_samples) {
  WindowLimits l;
  // With fewer samples than unknowns (plus the start's four) the fit is underdetermined and
  // fails without a useful reason; say why up front.
  l.min_samples = std::max(8, space.n_unknowns() + 5);
  l.max_samples = std::min(max_samples, kMaxWindowSamples);
  l.mode1_hz = modal.modes().front().frequency_hz;
  l.min_frequency_hz = l.mode1_hz / 10;
  l.max_frequency_hz = modal.modes().back().frequency_hz * 10;
  l.length_m = cantilever_length_m;
  l.max_amplitude_m = cantilever_length_m > 0 ? cantilever_length_m : kCalibratedProbeMaxAmplitudeM;
  l.amplitude_from_window = space.from_window("drive_amplitude_m");
  l.frequency_from_window = space.from_window("drive_frequency_hz");
  l.phase_from_window = space.from_window("drive_phase_rad");
  l.chirp_from_window = space.from_window("drive_chirp_hz_per_s");
  return l;
}

std::optional<std::string> window_problem_for_probe(const Window& w, const WindowLimits& l) {
  const int n = w.n_samples();
  const double dt = w.sample_period_s;
  if (n < l.min_samples)
    return "window has " + std::to_string(n) + " samples; at least " + std::to_string(l.min_samples) +
           " are needed to estimate the unknowns and the start";
  if (n > l.max_samples)
    return "window has " + std::to_string(n) + " samples, more than the limit of " + std::to_string(l.max_samples) +
           " (daemon.max_window_samples)";
  if (dt < l.min_sample_period_s)
    return "sample_period_s " + num(dt) + " s is below " + num(l.min_sample_period_s) +
           " s (faster than 10 GHz sampling)";
  const double nyquist_hz = 0.5 / dt;
  if (l.mode1_hz >= nyquist_hz)
    return "sample_period_s " + num(dt) + " s cannot resolve the probe's first mode (" + num(l.mode1_hz) +
           " Hz is above the Nyquist frequency " + num(nyquist_hz) + " Hz)";
  if (std::abs(w.t0_s) > l.max_abs_t0_s)
    return "t0_s " + num(w.t0_s) + " s is beyond +-" + num(l.max_abs_t0_s) +
           " s (the drive's phase would lose its precision)";
  const std::string length =
      l.length_m > 0 ? "the cantilever's length (" + num(l.length_m) + " m)" : "1 mm (a calibrated probe)";
  const Drive& d = w.drive;
  if (d.kind == DriveKind::sampled) {
    for (std::size_t i = 0; i < d.base_m.size(); ++i)
      if (std::abs(d.base_m[i]) >= l.max_amplitude_m)
        return "base sample " + std::to_string(i) + " (" + num(d.base_m[i]) + " m) is not below " + length;
    return std::nullopt;
  }
  if (l.amplitude_from_window && std::abs(d.amplitude_m) >= l.max_amplitude_m)
    return "drive_amplitude_m " + num(d.amplitude_m) + " m is not below " + length;
  if (l.phase_from_window && std::abs(d.phase_rad) > l.max_abs_phase_rad)
    return "drive_phase_rad " + num(d.phase_rad) + " is beyond +-" + num(l.max_abs_phase_rad) + " rad";
  auto frequency_problem = [&](double f, const std::string& what) -> std::optional<std::string> {
    if (f >= nyquist_hz)
      return what + " " + num(f) + " Hz is not below the Nyquist frequency " + num(nyquist_hz) + " Hz of the sampling";
    if (f < l.min_frequency_hz || f > l.max_frequency_hz)
      return what + " " + num(f) + " Hz is outside " + num(l.min_frequency_hz) + " .. " + num(l.max_frequency_hz) +
             " Hz (a decade around the probe's modes)";
    return std::nullopt;
  };
  if (l.frequency_from_window) {
    if (auto p = frequency_problem(d.frequency_hz, "drive_frequency_hz")) return p;
    // y = a sin(2 pi (f + g t) t): the instantaneous frequency is f + 2 g t; it must stay in
    // range from the window's first sample to its last.
    if (d.kind == DriveKind::chirp && l.chirp_from_window) {
      for (double t : {w.t0_s, w.t0_s + n * dt})
        if (auto p = frequency_problem(d.frequency_hz + 2 * d.chirp_hz_per_s * t,
                                       "the chirp's instantaneous frequency at t = " + num(t) + " s,"))
          return p;
    }
  } else if (d.kind == DriveKind::chirp && l.chirp_from_window) {
    // The frequency is fixed or estimated elsewhere; the chirp alone must not sweep past the modes.
    const double sweep = 2 * std::abs(d.chirp_hz_per_s) * std::max(std::abs(w.t0_s), std::abs(w.t0_s + n * dt));
    if (sweep > l.max_frequency_hz)
      return "drive_chirp_hz_per_s " + num(d.chirp_hz_per_s) + " sweeps " + num(sweep) + " Hz, beyond " +
             num(l.max_frequency_hz) + " Hz (a decade above the probe's modes)";
  }
  return std::nullopt;
}

}  // namespace tipforce
