#pragma once
// The 1-sigma values: the Gauss-Newton covariance at the answer, scaled by the residual variance
// (HAC-inflated for autocorrelated residuals), updated by the start prior and by the bounds, with
// the start shifts marginalised out.
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Dense>

#include "tipforce/inversion.hpp"

namespace tipforce::inversion {

// The inverse of a symmetric positive semi-definite matrix, or nothing where it is (numerically)
// singular: an eigenvalue below min_rel_eigenvalue times the largest. Judged and inverted at unit
// diagonal (the correlation form), so that an unknown the signal barely moves (small diagonal:
// poor precision) is not mistaken for a degenerate one (columns that repeat one another).
std::optional<Eigen::MatrixXd> inverse_spd(const Eigen::MatrixXd& a, double min_rel_eigenvalue);

// The factor by which autocorrelated residuals inflate the variance of a least-squares estimate
// over white ones: 1 + 2 sum_k w_k rho_k over lags 1..max_lags with Bartlett weights
// w_k = 1 - k / (max_lags + 1) (Newey and West 1987), at least 1. White noise leaves it near 1;
// structure the model cannot follow shrinks the number of independent samples.
double hac_inflation(const Eigen::VectorXd& residual, int max_lags);

struct Uncertainty {
  std::vector<double> sigma;           // per unknown; infinity where unknown
  std::vector<bool> determined;
  Eigen::MatrixXd covariance;          // of the unknowns, physical units
  // All packed unknowns (normalised, start shifts included): what the end state inherits.
  Eigen::MatrixXd full_covariance;
  // The same without the bounds' information (empty where the data and prior alone leave a
  // direction undetermined): what a pooled next window inherits, which adds the bounds itself.
  Eigen::MatrixXd data_covariance;
  bool identifiable = true;            // the data (and start prior) alone leave no direction undetermined
  double noise_var_m2 = 0;             // the residual variance the covariance was scaled with (0: none)
  std::string notes;                   // "...; " each
};

// At the answer: `lin` (N residuals, n_packed columns), its sum of squared residuals `cost`, the
// prior's information on the packed unknowns (StartPrior::packed_information; empty: flat), the unknowns' widths and names,
// and the answer's normalised unknowns x (for the at-bound notes). The residual variance is at
// least min_noise_var_m2 (the forward model's own error: InversionOptions::min_noise_rel).
Uncertainty posterior_uncertainty(const Eigen::MatrixXd& J, const Eigen::VectorXd& r, double cost,
                                  const Eigen::MatrixXd& prior_information, const std::vector<double>& widths,
                                  const std::vector<std::string>& names, const std::vector<double>& x,
                                  const InversionOptions& options, double min_noise_var_m2 = 0);

}  // namespace tipforce::inversion
