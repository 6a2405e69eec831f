#pragma once
// The forward problem: many parameter sets of one window at once (SPEC section 2).
//
// Scheme: each mode's linear part is integrated exactly by its 2x2 transition matrix, and a sine
// drive exactly by its closed-form steady state (a chirp or a sampled base through a quartic hold
// of the base acceleration). Free flight takes one exact step per sample. Where the tip touches
// the surface the tip-sample force is held as the quartic through its values at the step's five
// Lobatto points, the four after the start solved implicitly (exponential Lobatto collocation:
// eighth order for a smooth force, stable for any contact stiffness), in 2^j substeps where the
// contact is stiff; a step across contact onset or release locates the crossing. Details and
// the error analysis: lib/src/DESIGN.md.
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "tipforce/cantilever.hpp"
#include "tipforce/force_model.hpp"
#include "tipforce/window.hpp"

namespace tipforce {

// Modal coordinates and velocities at one instant.
struct ModalState {
  std::vector<double> q;  // per mode
  std::vector<double> v;  // per mode
  static ModalState rest(int n_modes) { return {std::vector<double>(n_modes, 0.0), std::vector<double>(n_modes, 0.0)}; }
};

// The free (no tip-sample force) steady-state response of every mode to a sine base motion of
// amplitude_m at frequency_hz and phase_rad, at time t_s: closed form, from the modal model alone
// (lib/src/steady_state.cpp).
ModalState linear_steady_state(const ModalModel& modal, double amplitude_m, double frequency_hz, double phase_rad,
                               double t_s);

// Per-mode exact discretisation of one step of length dt_s. Arrays are indexed by mode.
// A modal force (or base acceleration) over the step is held as the quartic through its values at
// the five Lobatto points of the step (kHoldNodes: 0, 1/2 -+ sqrt(21)/14, 1/2, 1 of the step); its
// response is exact for that hold. lib/src/DESIGN.md has the scheme.
inline constexpr int kHoldPoints = 5;
inline constexpr double kHoldNodes[kHoldPoints] = {0.0, 0.17267316464601142810, 0.5, 0.82732683535398857190, 1.0};
struct StepCoefficients {
  double dt_s = 0;
  int n_modes = 0;
  // Transition matrix [[a00, a01], [a10, a11]] over dt, and back over dt (u..): a step undone.
  std::vector<double> a00, a01, a10, a11;
  std::vector<double> u00, u01, u10, u11;
  // back[n]: the transition back from the step's end to its interior point n + 1 (over
  // (1 - node) dt), as [00, 01, 10, 11] per mode: back[n][4 * i + r].
  std::vector<double> back[kHoldPoints - 2];
  // end_q[k][i], end_v[k][i]: response (q, v) at the step's end to a unit modal force held as the
  // quartic with value 1 at point k and 0 at the others; at_q[n][k][i], at_v: the same at interior
  // point n + 1.
  std::vector<double> end_q[kHoldPoints], end_v[kHoldPoints];
  std::vector<double> at_q[kHoldPoints - 2][kHoldPoints], at_v[kHoldPoints - 2][kHoldPoints];
};
// Throws std::invalid_argument where step_problem names one.
StepCoefficients make_step_coefficients(const ModalModel& modal, double dt_s);
// Why the modes cannot be stepped at dt_s (a heavily damped high mode's step back would overflow),
// naming the mode; nullopt when they can. Two matrix exponentials per mode: a cheap check.
std::optional<std::string> step_problem(const ModalModel& modal, double dt_s);

// Everything a backend needs that does not change between parameter sets.
struct ForwardProblem {
  const ModalModel* modal = nullptr;
  const StepCoefficients* step = nullptr;  // for sample_period_s / substeps
  ForceModelKind model = ForceModelKind::none;
  const Window* window = nullptr;
  int substeps = 1;  // coarse solver steps per sample (1: contact refines by itself)
  // Phase of the contact oscillation one substep may span (rad); 0: the model's default
  // (default_contact_rad_per_substep). Infinity turns the refinement off (one step per coarse
  // step, for convergence studies).
  double contact_rad_per_substep = 0;
  // The same for a step in which the tip reaches or leaves the surface, where the scheme's error
  // comes from (finer; never coarser than the contact around it); 0: the model's default
  // (default_crossing_rad_per_substep). Infinity: crossings at the contact's own level.
  double crossing_rad_per_substep = 0;
  // Samples per coarse step, 1 or 2 (two: one step spans two sample periods, the odd samples at
  // its midpoint); 0: the solver's choice, 2 where the sample period is short against the
  // cantilever's first mode (lib/src/DESIGN.md). step stays the sample period's / substeps.
  int samples_per_step = 0;
};

// The crossings' resolution that, with default_contact_rad_per_substep, keeps every model within
// 1e-4 of the reference (lib/src/DESIGN.md).
double default_crossing_rad_per_substep(ForceModelKind model);

// The contact phase per substep that keeps each model within 1e-4 of the reference at every
// sample period, chosen by measurement (lib/src/DESIGN.md).
double default_contact_rad_per_substep(ForceModelKind model);

// Coarse steps per sample: 1 for every model, since contact substeps are chosen per step.
int default_substeps(ForceModelKind model);

struct ForwardBatch {
  int n_sets = 0;
  // Full parameter vectors (model parameters then drive parameters), structure of arrays:
  // params[k * n_sets + s] is parameter k of set s.
  std::span<const double> params;
  // One initial state shared by all sets, or one per set.
  std::span<const ModalState> initial;
  // False when every set has the same drive parameters (the drive is then evaluated once).
  bool drive_varies = false;
  bool want_signal = false;     // simulated measured signal per set
  bool want_end_state = false;  // state one sample period after the last sample
  bool want_force = false;      // tip-sample force and tip position per sample
  // CPU: sets [b x this, (b + 1) x this) share block b of the vector loop (0: the backend's
  // choice, which groups the sets by their contact's substep levels, then surface, then stiffness,
  // whatever their order in the batch).
  // The sets of a block take their contact substeps at the block's finest level, so a caller that
  // differences sets (a finite-difference Jacobian) keeps each difference inside one block; a
  // batch of a few sets in narrow blocks also runs on more than one core. The GPU solves each set
  // alone.
  int sets_per_block = 0;
};

struct ForwardOutput {
  std::vector<double> cost;        // sum of squared residuals against the window's deflection
  std::vector<double> signal;      // [set * n_samples + n]
  std::vector<double> force_n;     // [set * n_samples + n]
  std::vector<double> tip_z_m;     // [set * n_samples + n], absolute tip position
  std::vector<ModalState> end_state;
};

// A backend solves batches; the CPU backend always works, the CUDA backend where a GPU does.
class ForwardBackend {
 public:
  virtual ~ForwardBackend() = default;
  virtual std::string description() const = 0;  // e.g. "cpu: 2 threads"
  virtual void solve(const ForwardProblem& problem, const ForwardBatch& batch, ForwardOutput& out) = 0;
};

// SIMD over parameter sets, the batch split across threads.
// The CPU's vector units: `best` runs the forward step's AVX-512 or AVX2 clone where the CPU has it
// (chosen at load time), `baseline` the x86-64 baseline build of the same code (for comparison).
enum class CpuIsa { best, baseline };
std::unique_ptr<ForwardBackend> make_cpu_backend(int threads = 0 /* 0: hardware concurrency */,
                                                 CpuIsa isa = CpuIsa::best);

// Convenience: one parameter set, with signal, force, tip position and end state.
ForwardOutput simulate_one(ForwardBackend& backend, const ModalModel& modal, ForceModelKind model,
                           const Window& window, std::span<const double> full_params,
                           const ModalState& initial, int substeps = 0 /* 0: default_substeps */);

}  // namespace tipforce
