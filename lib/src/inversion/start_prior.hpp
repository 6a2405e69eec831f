#pragma once
// A continued window's prior on its start: what the previous fit knew about its end state, as
// Gaussian information on the start shifts, which this window's data then update (a Kalman
// step). Bounded by construction: information is only ever added, never inherited uncertainty.
#include <Eigen/Dense>

#include "inversion/batch_evaluator.hpp"
#include "inversion/coordinates.hpp"

namespace tipforce::inversion {

// The information matrix (inverse covariance) of a continued window's start shifts, in the
// window's scaled start coordinates (q / q_scale, v / v_scale per mode), from the previous fit's
// end-state covariance in physical units (q in m, v in m/s; modes interleaved). Its variances get
// a floor of floor_rel^2 in those coordinates: the forward solver's own error carried across the
// window edge, which no fit can remove, and a guard against an exactly singular covariance (a
// direction that the previous fit's parameters do not move) becoming infinite information.
Eigen::MatrixXd start_prior_information(const Eigen::MatrixXd& end_cov_phys, const Coordinates& coordinates,
                                        double floor_rel);

// The prior as the polish sees it: a quadratic penalty on the packed unknowns, in the cost's units
// (m^2: the information weighed by the previous fit's residual variance, so that cost / variance
// is the negative log posterior). On the start block alone (centred on no shift) unless pooled
// with the previous pixel's parameters (with_parameters). Flat (absent) for a start without a
// prior.
class StartPrior {
 public:
  // Flat: no information on n_packed unknowns.
  explicit StartPrior(int n_packed)
      : hessian_(Eigen::MatrixXd::Zero(n_packed, n_packed)), centre_(Eigen::VectorXd::Zero(n_packed)) {}
  StartPrior(Eigen::MatrixXd information, double noise_var_m2, int n_packed);

  // This prior and the previous pixel's parameters (parameter_prior.hpp): the joint Gaussian
  // prior on parameters and start, centred on the previous parameters and no start shift.
  // Requires a prior (present()).
  StartPrior with_parameters(const Eigen::MatrixXd& parameter_information, const Eigen::VectorXd& parameter_centre) const;

  bool present() const { return information_.rows() > 0; }
  // The information on the start block (scaled coordinates), empty when flat: the start's marginal
  // prior, which the start-conflict test measures against.
  const Eigen::MatrixXd& information() const { return information_; }
  // The information on all packed unknowns (normalised units), empty when flat.
  const Eigen::MatrixXd& packed_information() const { return packed_information_; }
  double noise_var_m2() const { return noise_var_m2_; }
  // Penalty at packed v, and its Hessian on all packed unknowns (zero where flat).
  double cost(const Eigen::VectorXd& packed) const;
  const Eigen::MatrixXd& hessian() const { return hessian_; }
  // The penalty's offset from its centre, v - centre (what the Hessian multiplies in its gradient).
  Eigen::VectorXd offset(const Eigen::VectorXd& packed) const { return pools_ ? Eigen::VectorXd(packed - centre_) : packed; }

 private:
  Eigen::MatrixXd information_;
  double noise_var_m2_ = 0;
  Eigen::MatrixXd packed_information_;  // empty when flat
  Eigen::MatrixXd hessian_;
  Eigen::VectorXd centre_;
  bool pools_ = false;
};

// Does the window continue the previous fit? The start-conflict chi-square at a fit made with
// the start prior (packed answer v, its linearisation lin): how far the data pull the start from
// where the prior holds it, measured as the chi-square the fit would gain if the start were
// freed from the prior, plus the prior's own penalty:
//   d2 = s' P^-1 s + g_s' (A^-1)_ss g_s,  g = J' r / sigma^2,  A = J' J / sigma^2 (+ the bounds),
// with s the fitted start shift, P^-1 the prior's information and sigma^2 the previous fit's
// noise variance. In the linear-Gaussian model this is the Kalman filter's normalised
// innovation on the start, the Mahalanobis distance between what the data alone say of the start
// and what the prior says, over their combined covariance: chi-square with 2 x start modes
// degrees of freedom when the window continues the fit. A window whose cantilever was elsewhere
// (the acquisition restarted, a window from another place of the scan) moves the start by many
// of the prior's sigmas and gives thousands.
double start_conflict_chi2(const Linearisation& lin, const StartPrior& prior, const Eigen::VectorXd& v, int n_unknowns);

}  // namespace tipforce::inversion
