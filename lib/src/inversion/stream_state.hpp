#pragma once
// What an Inverter keeps between the windows of its probe: the previous fit, which a continued
// window starts from and tracks, and the caches that depend on the sample period only.
#include <cstdint>
#include <limits>
#include <vector>

#include <Eigen/Dense>

#include "tipforce/forward.hpp"

namespace tipforce::inversion {

// The previous fit, as far as the next window may use it.
struct PreviousFit {
  // The warm start: the last trusted estimate (empty: none) and its misfit.
  std::vector<double> values, sigma;
  double misfit = std::numeric_limits<double>::infinity();
  // Its residual's rms per sample (m): the tracking test compares this window's with it, because
  // the detection noise it measures is the sensor's, while the relative misfit also moves with
  // the signal's own size (a window as the tapping sets in holds a larger signal than the next).
  double residual_rms_m = 0;
  // Its peak (repulsive) force magnitude: a changed pixel's candidates keep it (valley_start).
  double peak_force_n = 0;
  // Its residual variance: weighs the start prior in the misfit (0: none).
  double noise_var_m2 = 0;
  // The state one sample period after the last fitted sample, on the drive's clock, and the full
  // parameter vector it was fitted with (what a coast across a gap continues with).
  bool have_end_state = false;
  ModalState end_state;
  double end_t_s = 0;
  std::vector<double> full;
  long coasted_samples = 0;  // advanced across gaps since the fit (Inverter::coast_to), at most max_coast_samples
  // Covariance of that end state, start modes (q in m, v in m/s), when known: a continued
  // window's prior on its start, which its own data then update (never added on top).
  Eigen::MatrixXd end_cov;
  // With pooling (InversionOptions::parameter_drift_rel): the fit's parameters' covariance
  // (normalised to their bounds, without the bounds' own information) and its cross-covariance
  // with that end state (m x start block, physical units): the next window's prior on its
  // parameters (parameter_prior.hpp). Empty: none.
  Eigen::MatrixXd param_cov, param_end_cov;
  // The best so far of a fit that the deadline cut short (empty: none). With
  // InversionOptions::resume_cut_fits the next window of the line starts cold and polishes from
  // these values first (SolvePlan::resume_from): a cold start that a real-time budget cannot hold
  // in one window is spread over the next ones.
  std::vector<double> resume_values;

  bool has_warm_start() const { return !values.empty(); }
  // No prior for the next window, neither on its start nor on its parameters.
  void forget_prior() {
    end_cov.resize(0, 0);
    param_cov.resize(0, 0);
    param_end_cov.resize(0, 0);
  }
};

struct StreamState {
  PreviousFit previous;
  // The step coefficients for the last sample period.
  double step_dt_s = 0;
  StepCoefficients step;
  // The free decay from unit start shifts for the last window length and period.
  Eigen::MatrixXd unit_decay;
  double unit_decay_dt_s = 0;
  // The physics grid's wall time (one batch, which a deadline cannot cut), a running mean over the
  // grids scored so far; 0: none yet.
  double grid_seconds = 0;
};

}  // namespace tipforce::inversion
