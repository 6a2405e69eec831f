#pragma once
// Host-side preparation shared by the forward backends: per-set force constants, the tip's step
// response, and the drive evaluated once per window.
#include <span>
#include <vector>

#include "tipforce/detail/contact_step.hpp"
#include "tipforce/forward.hpp"

namespace tipforce::detail {

// Every backend's checks of a problem and batch, with the same messages: throws
// std::invalid_argument (the caller's mistake) naming what is wrong.
void check_forward_batch(const ForwardProblem& problem, const ForwardBatch& batch, int max_modes);

LaneForce make_lane_force(ForceModelKind model, std::span<const double> model_params);
// Reads set s of a structure-of-arrays batch.
LaneForce lane_force_of_set(ForceModelKind model, const ForwardBatch& batch, int set);

TipStepResponse tip_step_response(const ModalModel& modal, const StepCoefficients& step);

inline constexpr int kMaxModes = 32;

// Per-mode constants of one solve, indexed by mode; entries past the model's modes are zero.
// Plain arrays so that the CUDA kernel can take the struct by value.
struct ModeConstants {
  double a00[kMaxModes], a01[kMaxModes], a10[kMaxModes], a11[kMaxModes];       // transition matrix
  double cs_q[kMaxModes], cs_v[kMaxModes], ce_q[kMaxModes], ce_v[kMaxModes];   // (phi / mu L) * force holds
  double phi[kMaxModes], gain[kMaxModes], gamma[kMaxModes];                    // tip shape, sensor, base
  double wq0[kMaxModes], wv0[kMaxModes], wqm[kMaxModes], wvm[kMaxModes], wq1[kMaxModes], wv1[kMaxModes];
};
ModeConstants make_mode_constants(const ModalModel& modal, const StepCoefficients& step);

// The base motion of a window, evaluated once when every set shares the drive, on the solver's
// grid of N * substeps steps of h = sample_period_s / substeps:
//   y_m[j], ydot_m_per_s[j] for j = 0..N*substeps (the end state needs t0 + N dt), and the
//   drive's contribution to each mode over each step (quadratic hold of -gamma_i * yddot):
//   dq[j * modes + i], dv[j * modes + i] for j = 0..N*substeps-1.
struct SharedDrive {
  std::vector<double> y_m, ydot_m_per_s, dq, dv;
};
// drive_params: amplitude, frequency, phase, chirp (ignored for a sampled drive).
SharedDrive make_shared_drive(const ModalModel& modal, const StepCoefficients& step, const Window& window,
                              const double drive_params[4], int substeps = 1);

// Per-step drive contribution of one mode from base accelerations at the step's start, middle, end.
inline void drive_increment(const StepCoefficients& s, int mode, double gamma, double a0, double am, double a1,
                                 double& dq, double& dv) {
  dq = -gamma * (s.wq0[mode] * a0 + s.wqm[mode] * am + s.wq1[mode] * a1);
  dv = -gamma * (s.wv0[mode] * a0 + s.wvm[mode] * am + s.wv1[mode] * a1);
}

}  // namespace tipforce::detail
