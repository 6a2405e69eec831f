#pragma once
// Host-side preparation shared by the forward backends: per-set force constants, the per-level step
// constants, and the drive evaluated once per window.
#include <array>
#include <functional>
#include <span>
#include <vector>

#include "tipforce/detail/contact_step.hpp"
#include "tipforce/detail/forward_step.hpp"
#include "tipforce/detail/forward_window.hpp"
#include "tipforce/forward.hpp"
#include "tipforce/parameter_layout.hpp"

namespace tipforce::detail {

// Every backend's checks of a problem and batch, with the same messages: throws
// std::invalid_argument (the caller's mistake) naming what is wrong.
void check_forward_batch(const ForwardProblem& problem, const ForwardBatch& batch, int max_modes);

LaneForce make_lane_force(ForceModelKind model, const ForceParams& params);
// Reads set s of a structure-of-arrays batch.
LaneForce lane_force_of_set(ForceModelKind model, const ForwardBatch& batch, int set);

// The mode count a solve runs with: the model's modes padded with zero constants to 1, 2, 4, 8,
// 16 or 32 (a compile-time count: the per-mode loops unroll and the state stays in registers).
constexpr int padded_modes(int m) { return m <= 1 ? 1 : m <= 2 ? 2 : m <= 4 ? 4 : m <= 8 ? 8 : m <= 16 ? 16 : 32; }

// Per-mode constants of one step length, padded to P modes (forward_step.hpp).
template <int P>
StepConstants<P> make_step_constants(const ModalModel& modal, const StepCoefficients& step);

// The constants of a coarse step and of its refinements into 2, 4, ... kMaxSubsteps substeps
// (levels[j] has step h / 2^j), computed once per modal model and step: the refinements' exact
// discretisations cost milliseconds, a forward solve of a batch a fraction of that. Keeps the
// last few (model, step) pairs, so that one backend serving several probes in turn does not
// recompute them at every switch.
template <int P>
class StepLevels {
 public:
  // Runs fn(0) .. fn(n - 1), in any order and on any threads (the levels are independent).
  using ForEach = std::function<void(int n, const std::function<void(int)>& fn)>;
  // for_each: how to compute the levels of a new (model, step), e.g. on a thread pool; serial
  // when empty. The same arithmetic either way.
  // The levels of a coarse step of samples_per_step steps of `step`.
  const StepConstants<P>* get(const ModalModel& modal, const StepCoefficients& step, int samples_per_step,
                              const ForEach& for_each = {});

 private:
  // Keyed by the model's constants, not its address: a model assigned a new damping (or freed, and
  // another built where it was) with the same first frequency was answered with the old one's steps.
  struct Entry {
    std::vector<double> modal;  // append_modal_constants
    double h_s = 0;
    std::vector<StepConstants<P>> levels;
  };
  static constexpr std::size_t kEntries = 4;
  std::vector<Entry> entries_;  // most recently used last
  std::vector<double> key_;     // the model's constants of the current call (its storage reused)
};

// Appends what the step constants and a shared drive read of a modal model, by value: its mode
// count and sensor, the modal mass, and per mode the frequency, damping, gamma, tip shape and
// sensor gain. Two models with the same values step alike.
void append_modal_constants(const ModalModel& modal, std::vector<double>& out);
// Bit for bit (a NaN matches itself, -0 is not 0), as the arrays built from them would differ.
bool same_bits(const std::vector<double>& a, const std::vector<double>& b);

// Samples per coarse step (WindowSetup::samples_per_step): ForwardProblem::samples_per_step where
// set, else 2 where the sample period is at most 1 / (kTwoSampleStepsPerPeriod f1) (the coarse
// step, two sample periods, then stays at or below 1 / 100 of mode 1's period; the contact levels
// adapt to the contact as at any step) and the window allows it (one step per sample
// otherwise, two_samples_fit: substeps, an odd sample count, the optical lever, a drive per set, a sampled base:
// its acceleration is linear between samples with a kink at each, which one quartic hold over two
// samples cannot follow; with 0.1-1 % noise on the base that was 3e-2 to 5 off the reference at
// 1e-7 and 1e-8 s). Measured at 1e-7 s (spring, 8 modes, firm tapping): 1.5 x the solves/s of a
// step per sample, still within 1e-4 of the reference for every model (lib/src/DESIGN.md).
inline constexpr double kTwoSampleStepsPerPeriod = 200;
int samples_per_step(const ForwardProblem& problem, const ForwardBatch& batch);
// Whether the window and batch allow two samples per step at all (whatever the sample period).
bool two_samples_fit(const ForwardProblem& problem, const ForwardBatch& batch);

// What sizes contact substeps for this problem.
ContactResolution contact_resolution(const ModalModel& modal, const ForwardProblem& problem);

// The drive of a window when every set shares it, evaluated once, on the coarse grid of
// N * substeps steps of h = sample_period_s / substeps (forward_window.hpp's views point into it):
// a sine drive's phase, base and steady-state tip per coarse step and inner point; a held drive's
// base, tip base at the inner points and per-mode increments (padded to P modes), and for a sampled
// base its per-sample position, velocity and acceleration (finite differences), which the drive
// function interpolates for substeps. Valid while neither copied nor moved (the views point in).
struct SharedDrive {
  bool held = false;
  int padded = 0;
  std::vector<double> ph_s, ph_c, y, yd, zb, zbd, zbn, zbdn, qr, qi, dq, dv;
  std::vector<double> ys, vs, as;
  std::vector<double> ym;  // two samples per step: the base at each step's midpoint
  SharedSineView sine;
  SharedHeldView hold;

  // Every array, in one fixed order (the GPU backend packs them into one buffer in it).
  std::array<const std::vector<double>*, 16> arrays() const {
    return {&ph_s, &ph_c, &y, &yd, &zb, &zbd, &zbn, &zbdn, &qr, &qi, &dq, &dv, &ys, &vs, &as, &ym};
  }
};

// Points the views' arrays at where(array): the array's own storage on the host, its copy in
// device memory for the GPU. The views' other fields are left as they are.
template <class Where>
void point_views(const SharedDrive& d, Where where, SharedSineView& sine, SharedHeldView& held) {
  sine.ph_s = where(d.ph_s);
  sine.ph_c = where(d.ph_c);
  sine.y = where(d.y);
  sine.zb = where(d.zb);
  sine.zbd = where(d.zbd);
  sine.zbn = where(d.zbn);
  sine.zbdn = where(d.zbdn);
  sine.qr = where(d.qr);
  sine.qi = where(d.qi);
  sine.ym = where(d.ym);
  held.ym = where(d.ym);
  held.y = where(d.y);
  held.yd = where(d.yd);
  held.zbn = where(d.zbn);
  held.zbdn = where(d.zbdn);
  held.dq = where(d.dq);
  held.dv = where(d.dv);
  held.fn.ys = where(d.ys);
  held.fn.vs = where(d.vs);
  held.fn.as = where(d.as);
}
// drive_params: amplitude, frequency, phase, chirp (ignored for a sampled drive).
// c0: the coarse step's constants (levels[0]: samples_per_step sample periods / substeps).
template <int P>
void make_shared_drive(const StepConstants<P>& c0, const Window& window, const double drive_params[4], int substeps,
                       int samples_per_step, SharedDrive& out);

// Everything a window's shared drive depends on, by value: the drive (its parameters, or a sampled
// base's samples), the window's timing, the step and its substeps, the modes' constants and the
// padding. A backend keeps the drive it evaluated while the key's bytes stay the same, whatever
// objects the window and the step live in (an Inverter reuses both for the next window).
class SharedDriveKey {
 public:
  // Reuses its storage.
  void assign(const ModalModel& modal, const StepCoefficients& step, const Window& window,
              const double drive_params[4], int substeps, int samples_per_step, int padded);
  bool operator==(const SharedDriveKey& other) const;
  void swap(SharedDriveKey& other) noexcept { values_.swap(other.values_); }

 private:
  std::vector<double> values_;
};

// The drive of one set with the given parameters (analytic drives only).
DriveFunction analytic_drive(const Window& window, const double drive_params[4]);

}  // namespace tipforce::detail
