#pragma once
// Host-side preparation shared by the forward backends: per-set force constants, the tip's step
// response, and the drive evaluated once per window.
#include <span>
#include <vector>

#include "tipforce/detail/contact_step.hpp"
#include "tipforce/detail/forward_step.hpp"
#include "tipforce/forward.hpp"
#include "tipforce/parameter_layout.hpp"

namespace tipforce::detail {

// Every backend's checks of a problem and batch, with the same messages: throws
// std::invalid_argument (the caller's mistake) naming what is wrong.
void check_forward_batch(const ForwardProblem& problem, const ForwardBatch& batch, int max_modes);

LaneForce make_lane_force(ForceModelKind model, const ForceParams& params);
// Reads set s of a structure-of-arrays batch.
LaneForce lane_force_of_set(ForceModelKind model, const ForwardBatch& batch, int set);

TipStepResponse tip_step_response(const ModalModel& modal, const StepCoefficients& step);

// Per-mode constants of one step length, for up to kMaxModes modes (forward_step.hpp).
using ModeConstants = StepConstants<kMaxModes>;
ModeConstants make_mode_constants(const ModalModel& modal, const StepCoefficients& step);

// The constants of a coarse step and of its refinements into 2, 4, ... kMaxSubsteps substeps
// (levels[j] has step h / 2^j), computed once per modal model and step: the refinements' exact
// discretisations cost milliseconds, a forward solve of a batch a fraction of that.
class StepLevels {
 public:
  const ModeConstants* get(const ModalModel& modal, const StepCoefficients& coarse);

 private:
  const ModalModel* modal_ = nullptr;
  double omega1_ = 0, h_s_ = 0;
  int n_modes_ = 0;
  std::vector<ModeConstants> levels_;
};

// What sizes contact substeps for this problem.
ContactResolution contact_resolution(const ModalModel& modal, const ForwardProblem& problem);

// The base motion of a window, evaluated once when every set shares the drive, on the coarse grid
// of N * substeps steps of h = sample_period_s / substeps:
//   y_m[j], ydot_m_per_s[j] for j = 0..N*substeps (the end state needs t0 + N dt), and the
//   drive's contribution to each mode over each step (quadratic hold of -gamma_i * yddot):
//   dq[j * modes + i], dv[j * modes + i] for j = 0..N*substeps-1.
// A sampled drive also keeps its base position, velocity and acceleration per sample (ys, vs, as:
// N + 1 values, finite differences), which function() interpolates for substeps.
struct SharedDrive {
  std::vector<double> y_m, ydot_m_per_s, dq, dv;
  std::vector<double> ys, vs, as;
  DriveFunction fn;  // points into ys/vs/as: valid while this object is neither copied nor moved
};
// drive_params: amplitude, frequency, phase, chirp (ignored for a sampled drive).
void make_shared_drive(const ModalModel& modal, const StepCoefficients& step, const Window& window,
                       const double drive_params[4], int substeps, SharedDrive& out);

// The drive of one set with the given parameters (analytic drives only).
DriveFunction analytic_drive(const Window& window, const double drive_params[4]);

}  // namespace tipforce::detail
