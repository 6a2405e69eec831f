#pragma once
// Pooling across pixels (InversionOptions::parameter_drift_rel): the previous pixel's parameters
// as a Gaussian prior on this window's, which this window's data update, as a Kalman filter
// updates a random walk. The previous fit knew its parameters and its end state jointly (their
// errors correlate: a stiffer estimate ends the window elsewhere), and this window's start prior
// already carries the end state; so the parameters enter as the rest of that joint prior, the
// parameters given the start, and nothing the previous window knew is counted twice.
#include <optional>
#include <vector>

#include <Eigen/Dense>

#include "inversion/coordinates.hpp"
#include "inversion/start_prior.hpp"
#include "inversion/stream_state.hpp"

namespace tipforce::inversion {

// x | s ~ N(centre + regression s, covariance): the parameters (normalised) given the start
// shifts (scaled coordinates), with the drift of one window added.
struct ParameterPrior {
  Eigen::VectorXd centre;      // the previous fit's parameters (m)
  Eigen::MatrixXd regression;  // m x start block
  Eigen::MatrixXd covariance;  // m x m

  // H = [I, -regression] over the packed unknowns: the prior measures H v.
  Eigen::MatrixXd measurement() const;
  // Its information on the packed unknowns, H' covariance^-1 H (what StartPrior::with_parameters adds).
  Eigen::MatrixXd packed_information() const;
};

// From the previous fit (its parameters, their covariance and their cross-covariance with the end
// state, PreviousFit::param_cov and param_end_cov), this window's start prior information (in the
// start's scaled coordinates; start_prior_information) and each unknown's drift relative to its
// value (InversionOptions::parameter_drift_rel, in the unknowns' order; the value taken as at least
// a hundredth of the bounds' width). None when the previous
// fit hands on no such covariance, there is no drift, or the conditional covariance is not
// positive definite.
std::optional<ParameterPrior> parameter_prior(const PreviousFit& previous, const Coordinates& coordinates,
                                              const Eigen::MatrixXd& start_information,
                                              const std::vector<double>& drift_rel);

// A Kalman step on the packed unknowns from this window's own answer v (its covariance cov, with
// the start prior and the bounds): the normalised innovation y' S^-1 y of y = centre - H v with
// S = H cov H' + covariance (chi-square with m degrees of freedom where the sample does not
// change), and the updated point v + cov H' S^-1 y.
struct PoolingStep {
  double innovation_chi2 = 0;
  Eigen::VectorXd v;
};
PoolingStep pooling_step(const ParameterPrior& prior, const Eigen::VectorXd& v, const Eigen::MatrixXd& cov);

// The innovation measured on the model rather than on the window's linearisation: the joint
// negative log posterior at the pooled answer (its data's sum of squares, packed point and joint
// prior `pooled`) less the window's own (its data's, point and start prior `own`), in chi-square
// units of the noise variance data_var_m2 (the priors weigh their own). For a linear model at the
// pooled optimum it is pooling_step's innovation; where the window's valley is long and curved,
// the linearisation at one end misjudges it (InversionOptions::pool_valley_chi2).
double pooled_innovation_chi2(double pooled_data_cost_m2, const Eigen::VectorXd& pooled_v, const StartPrior& pooled,
                              double own_data_cost_m2, const Eigen::VectorXd& own_v, const StartPrior& own,
                              double data_var_m2);

}  // namespace tipforce::inversion
