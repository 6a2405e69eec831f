#pragma once
// The inverse problem for one probe: bounded PSO with a warm start, Levenberg-Marquardt polish,
// Gauss-Newton covariance, derived quantities (SPEC section 2).
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include <Eigen/Dense>

#include "tipforce/cantilever.hpp"
#include "tipforce/forward.hpp"
#include "tipforce/parameters.hpp"
#include "tipforce/window.hpp"

namespace tipforce {

struct InversionOptions {
  int swarm_size = 48;            // cold start
  int max_generations = 60;
  int warm_swarm_size = 12;       // warm start: seeded around the previous estimate
  int warm_max_generations = 5;
  int stall_generations = 6;      // stop the swarm when the best has not improved for this many
  double stall_rel_tolerance = 1e-4;
  int lm_max_iterations = 20;
  // The same for a window whose start is unknown: its polish moves four start unknowns along with
  // the parameters, down a curved valley (k against h against the start amplitude) that 20
  // iterations often leave early. Measured on 64 cold starts at 5 MHz (honesty_test): the truth
  // of k within 2 sigma for 83 % of them at 20, 93 % at 100, for 2 % more forward solves.
  int cold_lm_max_iterations = 100;
  // Levenberg-Marquardt's damping (Marquardt's scaling: lambda times the diagonal). Start nearly
  // Gauss-Newton (the swarm or the previous pixel put us close); after an accepted step relax by
  // /3, after a rejected one stiffen by x8 (asymmetric, so that a rejected step is not retried at
  // nearly the same length), and by x10 when the damped system could not be solved at all. At
  // most lm_max_tries damped solves per iteration: at x8 that spans ~14 decades of lambda.
  double lm_initial_lambda = 1e-3;
  double lm_lambda_down = 3.0;
  double lm_lambda_up = 8.0;
  double lm_lambda_up_singular = 10.0;
  double lm_min_lambda = 1e-12;  // below this the damping is lost in the diagonal's rounding anyway
  int lm_max_tries = 16;
  // Converged when an accepted step lowers the cost by less than this fraction (the noise's own
  // chi-square moves far more between windows) or moves no unknown by more than lm_step_tolerance
  // of its bounds' width (far below any sigma the data give).
  double lm_rel_cost_tolerance = 1e-7;
  double lm_step_tolerance = 1e-6;
  // ... or lowers the chi-square (cost / noise variance) by less than this: a step that gains
  // delta chi-square moves the estimate by about sqrt(delta) sigma, so further steps cannot change
  // the answer by more than a small fraction of its own uncertainty. 0 disables.
  double lm_chi2_tolerance = 1e-2;
  // A warm, continued window keeps the polish from the previous pixel (skipping the swarm) when its
  // relative misfit is at most ratio x the previous window's + slack. With N samples of white noise
  // the misfit itself scatters by ~1/sqrt(2N) (3.5 % at N = 400), so 1.15 is ~4 such scatters: a
  // pixel like its neighbour passes, an edge or a jump (misfit up by far more) goes to the swarm.
  // The slack keeps a nearly noiseless window (misfit ~0) from failing on rounding.
  double tracking_misfit_ratio = 1.15;
  double tracking_misfit_slack = 1e-4;
  // Above this relative misfit the model does not explain the window (30 % of the signal left
  // over is far beyond any detection noise): status NOT_CONVERGED.
  double max_misfit = 0.3;
  // Floor on the standard deviation of a continued window's inherited start (modes 1-2), relative
  // to the window's signal scale: the forward solver's own error over a window (SPEC: 1e-4)
  // carried across the edge, which keeps the prior from claiming more than the model can know.
  double start_prior_floor_rel = 1e-4;
  // The Gauss-Newton matrix (at unit diagonal) counts as singular below this eigenvalue relative
  // to its largest: about where double precision stops resolving two columns from one another.
  double singular_rel_eigenvalue = 1e-13;
  // A sigma above this fraction of the bounds' own spread ((high - low) / sqrt(12)) means that the
  // window hardly narrows what the bounds already said: the estimate notes it.
  double undetermined_sigma_fraction = 0.5;
  // Pairs more correlated than this are noted as trading off (SPEC: identifiability). 0.999:
  // such a pair's sigmas are at least ~22x those either would have with the other known.
  double trade_off_correlation = 0.999;
  // Contact phase per forward-solver substep during the swarm (ForwardProblem): the global search
  // needs the basin, not 1e-4, and its candidates include stiff contacts that a fine resolution
  // would split into many substeps; the polish and the covariance use the accurate default.
  double search_contact_rad_per_substep = 0.08;
  std::uint64_t seed = 1;
};

enum class EstimateStatus { ok = 0, not_converged = 1, rejected = 2 };

struct Estimate {
  EstimateStatus status = EstimateStatus::ok;
  std::string message;                    // why, when status is not ok
  std::vector<std::string> names;         // the unknowns
  std::vector<double> values;
  std::vector<double> sigma;              // 1-sigma
  // Per unknown: false where the window hardly narrows what the bounds already said (its sigma is
  // near their spread); the message says so too.
  std::vector<bool> determined;
  Eigen::MatrixXd covariance;
  double misfit = 0;                      // relative L2
  double peak_force_n = 0;                // largest repulsive force magnitude
  double mean_force_n = 0;
  double max_indentation_m = 0;
  double dissipated_energy_j = 0;         // per drive period
  int iterations = 0;                     // PSO generations + LM iterations
  int forward_solves = 0;
  double solve_seconds = 0;
};

// A probe: its modal model, force model and what is known about the parameters.
struct ProbeModel {
  std::string name;
  ModalModel modal;
  ParameterSpace space;
  InversionOptions options;
};

// Inverts the windows of one probe in order, carrying the warm start and the fitted end state
// from one window to the next. Not thread-safe; one per probe.
class Inverter {
 public:
  Inverter(ProbeModel probe, ForwardBackend& backend);

  // Never throws for bad data: a window that cannot be inverted gives status rejected.
  Estimate invert(const Window& window);

  // Forget the warm start and end state (e.g. after a gap in the stream).
  void reset();

  // Advances the last fitted end state across a gap (windows that never reached the inverter) to
  // t0_s with the last estimate, so that a window after the gap can continue from it rather than
  // start unknown. False, changing nothing, when there is no state to advance, the sample period
  // differs, t0_s lies before the end state, or the gap is longer than max_gap_samples.
  bool coast_to(double t0_s, double sample_period_s, int max_gap_samples = 50'000);
  bool has_warm_start() const { return !previous_values_.empty(); }
  // The last fit's end state (one sample period after its window's last sample), that instant on
  // the drive's clock, and the full parameter vector it was fitted with: where a prediction of
  // the next window starts (the setpoint advisor). nullptr when there is none (no fit yet, a
  // reset, a fit not trusted). Valid until the next call that changes the inverter.
  const ModalState* last_end_state() const { return have_end_state_ ? &previous_end_state_ : nullptr; }
  double last_end_t_s() const { return previous_end_t_s_; }
  const std::vector<double>& last_full_params() const { return previous_full_; }
  const ProbeModel& probe() const { return probe_; }
  ForwardBackend& backend() { return *backend_; }

 private:
  ProbeModel probe_;
  ForwardBackend* backend_;
  std::vector<double> previous_values_;
  std::vector<double> previous_sigma_;
  double previous_misfit_ = std::numeric_limits<double>::infinity();
  ModalState previous_end_state_;
  double previous_end_t_s_ = 0;          // drive-clock time of that end state
  std::vector<double> previous_full_;    // the full parameter vector it was fitted with
  // Covariance of that end state, modes 1-2 (q in m, v in m/s), when known: a continued window's
  // prior on its start, which its own data then update (never added on top).
  Eigen::MatrixXd previous_end_cov_;
  double previous_noise_var_m2_ = 0;  // the previous fit's residual variance: weighs that prior in the misfit
  Eigen::MatrixXd decay_unit_;        // free decay from unit start shifts of modes 1-2, per sample
  double decay_dt_s_ = 0;
  bool have_end_state_ = false;
  std::uint64_t windows_seen_ = 0;
  double cached_dt_s_ = 0;
  StepCoefficients step_;
};

}  // namespace tipforce
