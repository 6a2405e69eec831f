#include "inversion/levenberg_marquardt.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

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
    g = lin.J.transpose() * lin.r - prior.hessian() * v;
  }
};

PolishResult LevenbergMarquardt::minimise(LeastSquaresProblem& problem, const StartPrior& prior,
                                          const Eigen::VectorXd& start, const PolishSettings& settings,
                                          Linearisation& lin, const Deadline& deadline) const {
  // The step minimises the misfit plus the start prior's penalty; data_cost stays the misfit alone.
  Run run{problem, prior, settings, lin, deadline, start};
  run.linearise();
  run.lambda = settings.initial_lambda > 0 ? settings.initial_lambda : options_.lm_initial_lambda;
  iterate(run);
  return {run.v, run.data_cost, run.iterations, run.cut_short, run.gave_up};
}

void LevenbergMarquardt::iterate(Run& run) const {
  bool converged = false;
  for (; run.iterations < run.settings.max_iterations && !converged; ++run.iterations) {
    if (run.settings.give_up_after > 0 && run.iterations >= run.settings.give_up_after &&
        run.data_cost > run.settings.give_up_data_cost &&
        run.data_cost > run.settings.give_up_progress * run.data_cost_before_step) {
      run.gave_up = true;
      return;
    }
    if (!step(run, converged)) return;
  }
}

bool LevenbergMarquardt::step(Run& run, bool& converged) const {
  const int np = run.problem.n_packed(), m = run.problem.n_unknowns();
  const Linearisation keep = run.lin;
  for (int tries = 0; tries < options_.lm_max_tries; ++tries) {
    if (run.deadline.passed()) {
      run.cut_short = true;
      return false;
    }
    Eigen::MatrixXd Ad = run.A;
    for (int j = 0; j < np; ++j) Ad(j, j) += run.lambda * std::max(run.A(j, j), options_.lm_min_diagonal);
    const Eigen::LDLT<Eigen::MatrixXd> ldlt = Ad.ldlt();
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
    run.lambda *= options_.lm_lambda_up;
  }
  return false;
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

double LevenbergMarquardt::predicted_chi2_gain(const Run& run) const {
  const Eigen::VectorXd delta = run.A.ldlt().solve(run.g);
  return delta.allFinite() ? run.g.dot(delta) / run.noise_variance(run.data_cost) : INFINITY;
}

}  // namespace tipforce::inversion
