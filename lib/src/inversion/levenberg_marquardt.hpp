#pragma once
// The polish: Levenberg-Marquardt with Marquardt's diagonal scaling, on any least-squares problem
// linearised one point per batch (LeastSquaresProblem), plus a quadratic prior on the start block.
// Each trial point is linearised with its Jacobian in one batch, so an accepted step needs no
// second evaluation.
#include <Eigen/Dense>

#include "inversion/batch_evaluator.hpp"
#include "inversion/deadline.hpp"
#include "inversion/start_prior.hpp"
#include "tipforce/inversion.hpp"

namespace tipforce::inversion {

class LeastSquaresProblem {
 public:
  virtual ~LeastSquaresProblem() = default;
  virtual int n_residuals() const = 0;
  virtual int n_packed() const = 0;
  // The first n_unknowns packed coordinates are the parameters, normalised to their bounds (the
  // step tolerance is on them); the rest are the start shifts. Every linearisation recomputes
  // all columns.
  virtual int n_unknowns() const = 0;
  // The feasible point nearest v (parameters clamped to their bounds).
  virtual Eigen::VectorXd project(const Eigen::VectorXd& v) const = 0;
  // The sum of squared residuals at feasible v, with the residual and Jacobian in lin.
  virtual double linearise(const Eigen::VectorXd& v, Linearisation& lin) = 0;
  // f(probe) - f(v), the model's change between two feasible points (for geodesic acceleration;
  // v is the current linearisation's point); empty: the problem offers none, and the polish takes
  // plain Levenberg-Marquardt steps.
  virtual Eigen::VectorXd model_difference(const Eigen::VectorXd&, const Eigen::VectorXd&) { return {}; }
};

struct PolishSettings {
  int max_iterations = 20;
  // The damping the first step tries (0: InversionOptions::lm_initial_lambda).
  double initial_lambda = 0;
  // The noise variance per residual that chi-square is measured in; 0: the residuals' own
  // (cost / (residuals - unknowns)).
  double noise_var_m2 = 0;
  // ... at least this (the forward model's own error: InversionOptions::min_noise_rel).
  double min_noise_var_m2 = 0;
  // Give up after this many iterations (0: never) while the misfit is still above
  // give_up_data_cost: a tracking polish that is this far from the previous pixel's misfit after
  // a few steps is crawling along a valley towards another domain (an edge), which a search
  // reaches for fewer forward solves than the rest of the crawl.
  // ... and only while the last step kept more than give_up_progress of the misfit's cost (a
  // crawl: a polish converging from nearby cuts it by far more per step).
  // ... and, with give_up_predicted, before the first step already when the start's own
  // linearisation predicts that an exact Gauss-Newton step would fail both tests (its
  // prediction is optimistic along a curved valley, so such a step fails them too).
  // Geodesic acceleration of the steps (InversionOptions::lm_geodesic_*), where the problem offers
  // a residual.
  bool geodesic = false;
  int give_up_after = 0;
  double give_up_data_cost = 0;
  double give_up_progress = 1.0;
  bool give_up_predicted = false;
};

struct PolishResult {
  Eigen::VectorXd v;     // the answer (packed)
  double data_cost = 0;  // its sum of squared residuals, without the prior
  int iterations = 0;
  bool cut_short = false;  // stopped at the deadline (checked before each damped try)
  bool gave_up = false;    // stopped by give_up_after
};

class LevenbergMarquardt {
 public:
  explicit LevenbergMarquardt(const InversionOptions& options) : options_(options) {}

  // From feasible `start`. On return `lin` holds the linearisation at the answer (the best point
  // so far when cut short at the deadline).
  PolishResult minimise(LeastSquaresProblem& problem, const StartPrior& prior, const Eigen::VectorXd& start,
                        const PolishSettings& settings, Linearisation& lin,
                        const Deadline& deadline = Deadline()) const;

 private:
  struct Run;
  void iterate(Run& run) const;
  // One iteration: damped steps until one lowers the cost (or lm_max_tries); false if none did.
  bool step(Run& run, bool& converged) const;
  bool accelerate(Run& run, const Eigen::LDLT<Eigen::MatrixXd>& ldlt, Eigen::VectorXd& delta) const;
  // The chi-square an exact Gauss-Newton step from the current point would still gain.
  double predicted_chi2_gain(const Run& run) const;
  // The misfit's cost (without the prior) after an exact Gauss-Newton step from the current point,
  // by its linearisation.
  double predicted_data_cost(const Run& run) const;
  bool gives_up(const Run& run) const;
  double lambda_after_rejection(const Run& run, const Eigen::VectorXd& step, double trial_cost) const;

  const InversionOptions& options_;
};

}  // namespace tipforce::inversion
