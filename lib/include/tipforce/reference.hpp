#pragma once
// An independent reference integrator: Boost.Odeint's adaptive Dormand-Prince 5(4) on the
// modal equations with the drive evaluated analytically and contact switches located as events
// (bisection to the switching surface, then restart). Slow and tight; used to check the forward
// solver, to make synthetic data, and as the benchmark's baseline (with fixed-step RK4).
#include <span>
#include <vector>

#include "tipforce/cantilever.hpp"
#include "tipforce/force_model.hpp"
#include "tipforce/forward.hpp"
#include "tipforce/window.hpp"

namespace tipforce {

// Tolerances of the adaptive stepper. The absolute one is in metres (modal coordinates, and
// velocities scaled by omega_1): signals are tens of nanometres, and at 1e-13 the reference was
// off by 2e-4 for the DMT laws, more than the forward solver it checks.
struct ReferenceOptions {
  double abs_tol = 1e-16;
  double rel_tol = 1e-12;
};

struct ReferenceResult {
  std::vector<double> signal;   // per sample
  std::vector<double> force_n;  // per sample
  std::vector<double> tip_z_m;  // per sample
  ModalState end_state;         // one sample period after the last sample
};

ReferenceResult reference_simulate(const ModalModel& modal, ForceModelKind model, const Window& window,
                                   std::span<const double> full_params, const ModalState& initial,
                                   const ReferenceOptions& options = {});

// The benchmark's baseline: classic fixed-step RK4 (odeint runge_kutta4), one step per sample,
// no event handling. Returns the signal.
std::vector<double> odeint_rk4_simulate(const ModalModel& modal, ForceModelKind model, const Window& window,
                                        std::span<const double> full_params, const ModalState& initial);

// How far a signal is from a reference one: ||signal - reference|| / ||reference|| over the
// reference's samples (SPEC: the forward solver within 1e-4 of the reference integrator).
double relative_l2_error(std::span<const double> signal, std::span<const double> reference);

}  // namespace tipforce
