#include "inversion/levenberg_marquardt.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

namespace tipforce::inversion {

struct LevenbergMarquardt::Run {
  LeastSquaresProblem& problem;
  const StartPrior& prior;
  const PolishSettings& settings;
  Linearisation& lin;
  const Deadline& deadline;
  Eigen::VectorXd v;
  // The normal equations at v (prior included), A delta = g: each step's damped systems and the
  // predicted gain at an accepted point both solve them.
  Eigen::MatrixXd A{};
  Eigen::VectorXd g{};
  // Marquardt's scaling: A's diagonal, at least min_diagonal (InversionOptions::lm_min_diagonal),
  // which damps each step and measures its length.
  Eigen::VectorXd D{};
  double min_diagonal = 0;
  double data_cost = 0, cost = 0, lambda = 0;
  double data_cost_before_step = std::numeric_limits<double>::infinity();
  int iterations = 0;
  bool cut_short = false, gave_up = false;

  // The noise's variance per residual: the cost's natural unit (chi-square = cost / it).
  double noise_variance(double data_cost_m2) const {
    return std::max(settings.min_noise_var_m2,
                    settings.noise_var_m2 > 0 ? settings.noise_var_m2
                                              : data_cost_m2 / std::max(1, problem.n_residuals() - problem.n_packed()));
  }
  void linearise() {
    data_cost = problem.linearise(v, lin);
    cost = data_cost + prior.cost(v);
    form_normal_equations();
  }
  void form_normal_equations() {
    A = lin.J.transpose() * lin.J + prior.hessian();
    g = lin.J.transpose() * lin.r - prior.hessian() * prior.offset(v);
    D = A.diagonal().cwiseMax(min_diagonal);
  }
  Eigen::MatrixXd damped(double damping) const {
    Eigen::MatrixXd Ad = A;
    Ad.diagonal() += damping * D;
    return Ad;
  }
  double scaled_norm(const Eigen::VectorXd& step) const { return std::sqrt((D.array() * step.array().square()).sum()); }
  // The undamped step: what an exact Gauss-Newton step from v would do.
  Eigen::VectorXd gauss_newton_step() const { return A.ldlt().solve(g); }
};

PolishResult LevenbergMarquardt::minimise(LeastSquaresProblem& problem, const StartPrior& prior,
                                          const Eigen::VectorXd& start, const PolishSettings& settings,
                                          Linearisation& lin, const Deadline& deadline) const {
  // The step minimises the misfit plus the start prior's penalty; data_cost stays the misfit alone.
  Run run{problem, prior, settings, lin, deadline, start};
  run.min_diagonal = options_.lm_min_diagonal;
  run.linearise();
  run.lambda = settings.initial_lambda > 0 ? settings.initial_lambda : options_.lm_initial_lambda;
  iterate(run);
  return {run.v, run.data_cost, run.iterations, run.cut_short, run.gave_up};
}

void LevenbergMarquardt::iterate(Run& run) const {
  bool converged = false;
  for (; run.iterations < run.settings.max_iterations && !converged; ++run.iterations) {
    if (gives_up(run)) {
      run.gave_up = true;
      return;
    }
    if (!step(run, converged)) return;
  }
}

bool LevenbergMarquardt::gives_up(const Run& run) const {
  const PolishSettings& s = run.settings;
  if (s.give_up_after <= 0) return false;
  if (run.iterations >= s.give_up_after)
    return run.data_cost > s.give_up_data_cost && run.data_cost > s.give_up_progress * run.data_cost_before_step;
  if (run.iterations > 0 || !s.give_up_predicted) return false;
  const double predicted = predicted_data_cost(run);
  return predicted > s.give_up_data_cost && predicted > s.give_up_progress * run.data_cost;
}

bool LevenbergMarquardt::step(Run& run, bool& converged) const {
  const int m = run.problem.n_unknowns();
  const Linearisation keep = run.lin;
  for (int tries = 0; tries < options_.lm_max_tries; ++tries) {
    if (run.deadline.passed()) {
      run.cut_short = true;
      return false;
    }
    const Eigen::LDLT<Eigen::MatrixXd> ldlt = run.damped(run.lambda).ldlt();
    Eigen::VectorXd delta = ldlt.solve(run.g);
    if (!delta.allFinite()) {
      run.lambda *= options_.lm_lambda_up_singular;
      continue;
    }
    if (run.settings.geodesic && !accelerate(run, ldlt, delta)) {
      run.lambda *= options_.lm_lambda_up;
      continue;
    }
    const Eigen::VectorXd cand = run.problem.project(run.v + delta);
    const double c_data = run.problem.linearise(cand, run.lin);
    const double c = c_data + run.prior.cost(cand);
    if (c < run.cost) {
      const double rel = (run.cost - c) / run.cost;
      const double step_size = m > 0 ? delta.head(m).cwiseAbs().maxCoeff() : 0.0;
      const double chi2_drop = (run.cost - c) / run.noise_variance(c_data);
      run.data_cost_before_step = run.data_cost;
      run.v = cand;
      run.cost = c;
      run.data_cost = c_data;
      run.lambda = std::max(run.lambda / options_.lm_lambda_down, options_.lm_min_lambda);
      run.form_normal_equations();
      // Converged: the cost no longer moves (relatively, or in chi-square: then the estimate
      // moves by a small fraction of its sigma), or the step is a millionth of the bounds, or
      // (from the new point's own linearisation) an exact Gauss-Newton step would gain less
      // than that chi-square: a step that lands on the minimum is recognised there, not by a
      // second step that gains nothing (which cost a whole linearisation: on tipforce bench's
      // 1 MHz line 113 of 200 windows now take one step, 37 -> 26 solves per window, one build).
      converged = rel < options_.lm_rel_cost_tolerance || chi2_drop < options_.lm_chi2_tolerance ||
                  step_size < options_.lm_step_tolerance ||
                  predicted_chi2_gain(run) < options_.lm_chi2_tolerance;
      return true;
    }
    run.lin = keep;
    run.lambda = lambda_after_rejection(run, cand - run.v, c);
  }
  return false;
}

// Moré's rule for a rejected step ("The Levenberg-Marquardt algorithm: implementation and
// theory", 1978): the cost along the step as the parabola through its value and slope at the
// start and its value at the rejected trial; the next step is as long as that parabola's minimum
// lies along this one (between lm_min_shrink and lm_max_shrink of it, in Marquardt's scaled
// norm), and the damping that gives it is found by bisection (linear algebra only, no solve). A
// fixed factor took 3-5 rejected trials, each a whole linearisation, where the undamped step of a
// continued window overshot h into its bound (tools/bench_daemon.sh's stream).
double LevenbergMarquardt::lambda_after_rejection(const Run& run, const Eigen::VectorXd& step, double trial_cost) const {
  const double slope = -2.0 * run.g.dot(step);  // d cost / dt at t = 0 along v + t step
  const double bend = trial_cost - run.cost - slope;
  if (!options_.lm_interpolate_rejected || !(slope < 0) || !(bend > 0) || !std::isfinite(trial_cost))
    return run.lambda * options_.lm_lambda_up;
  const double t = std::clamp(-slope / (2.0 * bend), options_.lm_min_shrink, options_.lm_max_shrink);
  const double target = t * run.scaled_norm(step);
  auto step_norm = [&](double lambda) {
    const Eigen::VectorXd delta = run.damped(lambda).ldlt().solve(run.g);
    return delta.allFinite() ? run.scaled_norm(delta) : 0.0;
  };
  // The damped step's length falls as lambda grows: bracket the target by doubling from twice
  // the rejected lambda (at least that: a clamped step can be shorter than its unclamped length),
  // then bisect in log lambda to 1 %.
  double lo = std::max(run.lambda, options_.lm_min_lambda), hi = 2.0 * lo;
  for (int i = 0; i < 200 && step_norm(hi) > target; ++i) lo = std::exchange(hi, 2.0 * hi);
  for (int i = 0; i < 20 && hi > 1.01 * lo; ++i) {
    const double mid = std::sqrt(lo * hi);
    (step_norm(mid) > target ? lo : hi) = mid;
  }
  return std::max(hi, 2.0 * std::max(run.lambda, options_.lm_min_lambda));
}

// Geodesic acceleration (Transtrum and Sethna, "Improvements to the Levenberg-Marquardt algorithm
// for nonlinear least-squares minimization", 2012): the step's second-order correction from the
// model's second directional derivative along it, by a finite difference of one more solve. In a
// narrow curved valley (k against the indentation) a plain step is as long as the valley's
// curvature allows, and the polish zig-zags down it: a 1 MHz cold start took 18 iterations, every
// other one rejected. True: delta now holds the corrected step; false: the correction is too
// large for the expansion to hold (2 |a| > alpha |delta|), a reason to damp more.
bool LevenbergMarquardt::accelerate(Run& run, const Eigen::LDLT<Eigen::MatrixXd>& ldlt, Eigen::VectorXd& delta) const {
  const double h = options_.lm_geodesic_step;
  const Eigen::VectorXd probe = run.problem.project(run.v + h * delta);
  if (!((probe - (run.v + h * delta)).cwiseAbs().maxCoeff() == 0)) return true;  // at a bound: plain step
  const Eigen::VectorXd df = run.problem.model_difference(run.v, probe);
  if (df.size() != run.lin.r.size() || !df.allFinite()) return true;
  // The model's second directional derivative along delta, and the acceleration a = -(J'J +
  // lambda D)^-1 J' f_vv; the step is delta + a / 2, taken when 2 |a| <= alpha |delta| (their test).
  const Eigen::VectorXd fvv = (2.0 / h) * (df / h - run.lin.J * delta);
  const Eigen::VectorXd a = -ldlt.solve(run.lin.J.transpose() * fvv);
  if (!a.allFinite() || 2.0 * a.norm() > options_.lm_geodesic_alpha * delta.norm()) return false;
  delta += 0.5 * a;
  return true;
}

double LevenbergMarquardt::predicted_data_cost(const Run& run) const {
  const Eigen::VectorXd delta = run.gauss_newton_step();
  return delta.allFinite() ? (run.lin.r - run.lin.J * delta).squaredNorm() : 0.0;
}

double LevenbergMarquardt::predicted_chi2_gain(const Run& run) const {
  const Eigen::VectorXd delta = run.gauss_newton_step();
  return delta.allFinite() ? run.g.dot(delta) / run.noise_variance(run.data_cost) : INFINITY;
}

}  // namespace tipforce::inversion
