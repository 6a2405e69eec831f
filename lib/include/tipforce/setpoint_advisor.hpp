#pragma once
// The setpoint advisor (issue 13): from one window's fit, predict the next window's peak force as a
// function of the two setpoints an AFM user has, the free amplitude and the tip-sample separation,
// and ask for the change that keeps it under a limit. The physics only (no LCM); tipforced turns an
// Advice into a setpoint_command_t (msgs/setpoint_command_t.lcm, which documents the fields).
//
// How (README "Closing the loop"): every prediction is a forward solve of the next window (the same
// length and sample period, the drive continued, the cantilever starting from the fit's end
// state) with the fitted parameters and the setpoints changed: the separation h shifted by the z
// offset, the drive amplitude scaled to the requested free amplitude. The sensitivities are
// central differences of such solves; the correction is found by secant iteration on solves
// along the correction's path, so the predicted value after it carries no linearisation error of
// its own. Its uncertainty is the delta method through the estimate's covariance (central
// differences at +-1 sigma of each unknown), plus the second-order term's spread.
#include <limits>
#include <span>
#include <string>
#include <vector>

#include "tipforce/cantilever.hpp"
#include "tipforce/forward.hpp"
#include "tipforce/inversion.hpp"
#include "tipforce/parameters.hpp"
#include "tipforce/window.hpp"

namespace tipforce {

struct AdvisorOptions {
  // The limit on the peak (largest repulsive) tip-sample force of a window. Required (> 0).
  double max_peak_force_n = 0;
  // A correction aims the prediction at (1 - margin) x max_peak_force_n. The margin is for what the
  // prediction does not know. The forward solver's error (1e-4) and the iteration's tolerance
  // (aim_tolerance_rel) are far smaller; a change of material at the next pixel is far larger (a
  // soft-to-hard step raised the force 7-fold on the closed-loop test's line) and no margin short
  // of the whole range covers it. 0.15 covers a next pixel a little firmer than this one.
  double margin = 0.15;
  // ... and aims there with the prediction plus this many of its sigmas. 1: where the prediction is
  // sharp (firm contact, sigma a few % of the value) the limit then lies several sigmas above the
  // aim anyway; where it is not (a light contact, whose peak force the window hardly determines:
  // sigma about 3 x the value on the closed-loop test's soft domain), 2 kept the tip retracted
  // over the whole soft domain after a hard one, asking for ever smaller retractions.
  double sigma_multiplier = 1.0;
  // How far a correction may lower the free amplitude (m, absolute); it never raises it (that
  // raises the force). NaN (the default): the free amplitude is not touched and corrections
  // retract alone.
  double min_free_amplitude_m = std::numeric_limits<double>::quiet_NaN();
  // The largest retraction one command asks for (m). The advisor does not know the instrument's
  // z reference, so this bounds each step; the controller bounds the total.
  double max_z_step_m = 5e-9;
  // Finite-difference steps of the sensitivities: a tenth of a nanometre in separation (the
  // peak force is smooth in h while in contact, and 0.1 nm is far above the forward solver's
  // 1e-4 relative error), 1 % of the free amplitude.
  double z_step_m = 0.1e-9;
  double amplitude_step_rel = 0.01;
  // Secant iterations on the correction's size, and when to stop: the aim reached within 2 % of
  // the limit (each iteration is 1 + 2 x unknowns forward solves).
  int max_iterations = 4;
  double aim_tolerance_rel = 0.02;
};

// Why an AdvisorOptions cannot be used (naming the field), or empty.
std::string advisor_options_problem(const AdvisorOptions& options);

enum class AdviceStatus { under_limit = 0, correction = 1, out_of_range = 2, no_advice = 3 };

struct Advice {
  static constexpr double nan = std::numeric_limits<double>::quiet_NaN();
  AdviceStatus status = AdviceStatus::no_advice;
  std::string reason;
  double free_amplitude_m = nan;  // requested (absolute); the current one unless correcting
  double z_offset_m = 0;          // requested change of separation (+ retracts)
  double predicted_peak_force_n = nan, predicted_sigma_n = nan;  // next window, requested setpoints
  double hold_peak_force_n = nan, hold_sigma_n = nan;            // next window, setpoints unchanged
  double dpeak_dfree_amplitude_n_per_m = nan, dpeak_dz_n_per_m = nan;  // at the hold point
  double current_free_amplitude_m = nan;
  double separation_m = nan;  // fitted h of the answered window
  double target_peak_force_n = nan;
  int forward_solves = 0;
};

// What the advisor predicts from: one answered window and its fit.
struct FittedWindow {
  const Window* window = nullptr;
  const Estimate* estimate = nullptr;
  // The fit's state one sample period after the window's last sample, that instant on the drive's
  // clock, and the full parameter vector at the estimate (Inverter::last_fit). nullptr: none.
  const ModalState* end_state = nullptr;
  double end_t_s = 0;
  std::span<const double> full_params;
};

// Amplitude of the measured signal per metre of sine drive amplitude, far from the surface, in
// the free cantilever's steady state at frequency_hz (the linear modal response; the sensor's
// gains included).
double free_amplitude_per_drive_amplitude(const ModalModel& modal, double frequency_hz);

// One per probe; not thread-safe (it caches the step coefficients of the last sample period).
class SetpointAdvisor {
 public:
  // Throws std::invalid_argument when advisor_options_problem finds one.
  SetpointAdvisor(const ModalModel& modal, const ParameterSpace& space, AdvisorOptions options);

  // Never throws for a fit it cannot use: that is an Advice with status no_advice and the reason.
  Advice advise(const FittedWindow& fit, ForwardBackend& backend);

  const AdvisorOptions& options() const { return options_; }

 private:
  struct Setpoints {
    double free_amplitude_m;
    double z_offset_m;
  };
  struct Prediction {
    double peak_n = 0, sigma_n = 0;
  };
  class Solver;
  double aim_n() const { return (1 - options_.margin) * options_.max_peak_force_n; }
  // How far a prediction plus sigma_multiplier sigmas lies over the aim (negative: under).
  double excess(const Prediction& p) const { return p.peak_n + options_.sigma_multiplier * p.sigma_n - aim_n(); }
  // Over the aim with the setpoints held: the correction (CORRECTION or OUT_OF_RANGE).
  Advice correct(Solver& solver, const Prediction& hold, double gain, Advice advice, const std::string& note) const;

  ModalModel modal_;
  ParameterSpace space_;
  AdvisorOptions options_;
  double step_dt_s_ = 0;
  StepCoefficients step_;
};

}  // namespace tipforce
