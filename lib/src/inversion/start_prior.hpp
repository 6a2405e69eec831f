#pragma once
// A continued window's prior on its start: what the previous fit knew about its end state, as
// Gaussian information on the start shifts, which this window's data then update (a Kalman
// step). Bounded by construction: information is only ever added, never inherited uncertainty.
#include <Eigen/Dense>

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

// The prior as the polish sees it: a quadratic penalty on the packed unknowns' start block, in
// the cost's units (m^2: the information weighed by the previous fit's residual variance, so that
// cost / variance is the negative log posterior). Flat (absent) for a start without a prior.
class StartPrior {
 public:
  // Flat: no information on n_packed unknowns.
  explicit StartPrior(int n_packed) : hessian_(Eigen::MatrixXd::Zero(n_packed, n_packed)) {}
  StartPrior(Eigen::MatrixXd information, double noise_var_m2, int n_packed);

  bool present() const { return information_.rows() > 0; }
  // The information on the start block (scaled coordinates), empty when flat.
  const Eigen::MatrixXd& information() const { return information_; }
  double noise_var_m2() const { return noise_var_m2_; }
  // Penalty at packed v, and its Hessian on all packed unknowns (zero where flat).
  double cost(const Eigen::VectorXd& packed) const;
  const Eigen::MatrixXd& hessian() const { return hessian_; }

 private:
  Eigen::MatrixXd information_;
  double noise_var_m2_ = 0;
  Eigen::MatrixXd hessian_;
};

}  // namespace tipforce::inversion
