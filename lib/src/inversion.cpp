// The probe's stream of windows: validation, the window's start, one WindowSolver per window
// (lib/src/inversion/window_solver.cpp: tracking polish or swarm, Levenberg-Marquardt, covariance,
// derived quantities), and what a fit hands the next window. README "How it works" has the
// reasoning.
#include "tipforce/inversion.hpp"

#include <chrono>
#include <cmath>

#include "inversion/batch_evaluator.hpp"
#include "inversion/stream_state.hpp"
#include "inversion/window_solver.hpp"
#include "tipforce/assert.hpp"

namespace tipforce {

Inverter::Inverter(ProbeModel probe, ForwardBackend& backend)
    : probe_(std::move(probe)), backend_(&backend), state_(std::make_unique<inversion::StreamState>()) {
  const auto missing = probe_.space.missing();
  TIPFORCE_THROW_UNLESS(missing.empty(), "probe '" + probe_.name + "': parameter '" + (missing.empty() ? "" : missing[0]) +
                                             "' is neither fixed nor unknown");
}

Inverter::~Inverter() = default;
Inverter::Inverter(Inverter&&) noexcept = default;
Inverter& Inverter::operator=(Inverter&&) noexcept = default;

bool Inverter::has_warm_start() const { return state_->previous.has_warm_start(); }

void Inverter::reset() { state_->previous = inversion::PreviousFit{}; }

bool Inverter::coast_to(double t0_s, double sample_period_s, int max_gap_samples) {
  inversion::PreviousFit& p = state_->previous;
  if (max_gap_samples < 0) max_gap_samples = probe_.options.max_coast_samples;
  if (!p.have_end_state || p.full.empty() || sample_period_s != state_->step_dt_s) return false;
  const double gap = (t0_s - p.end_t_s) / sample_period_s;
  const long n_gap = std::lround(gap);
  if (!std::isfinite(gap) || n_gap < 0 || std::abs(gap - n_gap) > probe_.options.coast_grid_tolerance ||
      n_gap > max_gap_samples)
    return false;
  if (n_gap == 0) return true;
  p.end_state = inversion::BatchEvaluator::coast(*backend_, probe_.modal, probe_.space, state_->step, p.full,
                                                 p.end_state, p.end_t_s, sample_period_s, n_gap);
  p.end_t_s = t0_s;
  // The covariance belonged to the state before the gap; rather than carry it across (which would
  // need the gap's transition too), the window after the gap estimates its start from its own
  // data (a flat prior), which is honest if a little less precise.
  p.end_cov.resize(0, 0);
  return true;
}

Estimate Inverter::invert(const Window& w) {
  const auto t_start = std::chrono::steady_clock::now();
  Estimate est;
  if (auto problem = window_problem(w)) {
    est.names = probe_.space.unknown_names();
    est.status = EstimateStatus::rejected;
    est.message = *problem;
    est.misfit = std::nan("");
  } else {
    if (state_->step_dt_s != w.sample_period_s) {
      state_->step = make_step_coefficients(probe_.modal, w.sample_period_s / default_substeps(probe_.space.model()));
      state_->step_dt_s = w.sample_period_s;
    }
    InitialState start = w.initial;
    if (start == InitialState::continued && !state_->previous.have_end_state) start = InitialState::unknown;
    est = inversion::WindowSolver(probe_, *backend_, *state_, w, start).solve();
  }
  ++state_->windows_seen;
  est.solve_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count();
  return est;
}

}  // namespace tipforce
