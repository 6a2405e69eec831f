#pragma once
// Shared fixtures for the physics tests: the paper's cantilever and a window builder.
#include <algorithm>
#include <cmath>
#include <vector>

#include "tipforce/tipforce.hpp"

namespace tipforce::testing {

inline ProbeSpec paper_probe(int modes = 8) { return paper_probe_spec(modes); }

// Inversion options without a latency budget, for the tests of what fits find: the default
// deadline (1 s, a guard for a live stream) cut a 1 MHz viscous-DMT cold start when 4 test jobs
// shared 2 cores, and a cut fit seeds nothing, so the figures of the windows after it moved with
// the machine's load.
inline InversionOptions unbudgeted_options() {
  InversionOptions options;
  options.deadline_ms = 0;
  return options;
}

inline Window sine_window(int n, double a_m = 2e-9, double f_hz = 25600.0, double dt_s = 1e-7, double t0_s = 0.0) {
  Window w;
  w.sample_period_s = dt_s;
  w.t0_s = t0_s;
  w.drive.kind = DriveKind::sine;
  w.drive.amplitude_m = a_m;
  w.drive.frequency_hz = f_hz;
  w.deflection_m.assign(static_cast<std::size_t>(n), 0.0);
  return w;
}

// Full parameter vector: model parameters then the window's drive.
inline std::vector<double> full_params(std::vector<double> model, const Window& w) {
  for (double d : {w.drive.amplitude_m, w.drive.frequency_hz, w.drive.phase_rad, w.drive.chirp_hz_per_s}) model.push_back(d);
  return model;
}

// Tip amplitude of the free (no contact) steady state, from the closed form.
inline double free_tip_amplitude(const ModalModel& modal, double a_m, double f_hz) {
  double amp = 0;
  for (double t = 0; t < 1.0 / f_hz; t += 1.0 / (f_hz * 200)) {
    const ModalState s = linear_steady_state(modal, a_m, f_hz, 0.0, t);
    double u = 0;
    for (int i = 0; i < modal.n_modes(); ++i) u += modal.modes()[i].phi_tip * s.q[i];
    amp = std::max(amp, std::abs(u));
  }
  return amp;
}

inline double relative_l2(const std::vector<double>& a, const std::vector<double>& ref) { return relative_l2_error(a, ref); }

}  // namespace tipforce::testing
