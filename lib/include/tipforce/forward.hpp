#pragma once
// The forward problem: many parameter sets of one window at once (SPEC section 2).
//
// Scheme: each mode's linear part is integrated exactly by its 2x2 transition matrix; the base
// acceleration enters through a quadratic hold (sample, midpoint, sample); the tip-sample force
// through a first-order hold whose step-end value is solved implicitly from the tip's scalar step
// response (so stiff contacts stay stable). A step across contact onset or release replaces the
// linear hold by a piecewise-linear one broken at the located crossing, folded back onto the two
// hold values by matching its first two moments. Free flight takes one step per sample; a sample
// period in which any set touches the surface is split into substeps sized from the contact's
// frequency. Details and the error analysis: lib/src/DESIGN.md.
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

// Per-mode exact discretisation for one sample period. Arrays are indexed by mode.
struct StepCoefficients {
  double dt_s = 0;
  int n_modes = 0;
  // Transition matrix [[a00, a01], [a10, a11]].
  std::vector<double> a00, a01, a10, a11;
  // Response to a unit modal force held as (1 - s/dt) (start value) and s/dt (end value).
  std::vector<double> hq_start, hv_start, hq_end, hv_end;
  // Quadratic hold weights for the base acceleration at s = 0, dt/2, dt (position / velocity).
  std::vector<double> wq0, wv0, wqm, wvm, wq1, wv1;
};
StepCoefficients make_step_coefficients(const ModalModel& modal, double dt_s);

// Everything a backend needs that does not change between parameter sets.
struct ForwardProblem {
  const ModalModel* modal = nullptr;
  const StepCoefficients* step = nullptr;  // for sample_period_s / substeps
  ForceModelKind model = ForceModelKind::none;
  const Window* window = nullptr;
  int substeps = 1;  // coarse solver steps per sample (1: contact refines by itself)
  // Phase of the contact oscillation one substep may span (rad); 0: the model's default
  // (default_contact_rad_per_substep). Infinity turns the refinement off (a fixed step, for
  // convergence studies).
  double contact_rad_per_substep = 0;
  // Whether each contact step is also run at the next finer level and the two combined
  // (Richardson extrapolation, which cancels the scheme's second-order error term); unset: the
  // model's default (default_extrapolate_contact).
  std::optional<bool> extrapolate_contact = std::nullopt;
};

// The contact phase per substep and the extrapolation that keep each model within 1e-4 of the
// reference at every sample period, chosen by measurement (lib/src/DESIGN.md): extrapolated steps
// of 0.1 rad for spring, 0.04 for Kelvin-Voigt, 0.02 for Hertz (its onset, where the stiffness
// grows as the root of the penetration, is what limits it), 0.01 for viscous DMT; plain steps of
// 0.003 rad for DMT, whose error comes from its attraction zone, which extrapolation does not help.
double default_contact_rad_per_substep(ForceModelKind model);
bool default_extrapolate_contact(ForceModelKind model);

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
