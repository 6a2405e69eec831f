#include "inversion/parameter_prior.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace tipforce::inversion {

namespace {
constexpr double kDriftFloorOfWidth = 0.01;
}  // namespace

Eigen::MatrixXd ParameterPrior::measurement() const {
  const auto m = centre.size(), nb = regression.cols();
  Eigen::MatrixXd H(m, m + nb);
  H << Eigen::MatrixXd::Identity(m, m), -regression;
  return H;
}

Eigen::MatrixXd ParameterPrior::packed_information() const {
  const Eigen::MatrixXd H = measurement();
  return H.transpose() * covariance.ldlt().solve(H);
}

std::optional<ParameterPrior> parameter_prior(const PreviousFit& previous, const Coordinates& coordinates,
                                              const Eigen::MatrixXd& start_information,
                                              const std::vector<double>& drift_rel) {
  const int m = coordinates.n_unknowns(), nb = coordinates.n_start_block();
  if (drift_rel.size() != static_cast<std::size_t>(m) || m == 0 || coordinates.n_start_unknowns() != nb || start_information.rows() != nb ||
      previous.param_cov.rows() != m || previous.param_end_cov.rows() != m || previous.param_end_cov.cols() != nb ||
      previous.values.size() != static_cast<std::size_t>(m) || !previous.param_cov.allFinite() ||
      !previous.param_end_cov.allFinite())
    return std::nullopt;
  ParameterPrior p;
  p.centre.resize(m);
  Eigen::VectorXd drift_var(m);
  for (int j = 0; j < m; ++j) {
    const double value = previous.values[static_cast<std::size_t>(j)];
    p.centre(j) = coordinates.unit(j, value);
    // Relative to the value, but never below a hundredth of the bounds' width: an unknown at 0
    // (a damping, a viscosity) would otherwise get no drift, and its sigma would shrink without end.
    const double scale = std::max(std::abs(value), kDriftFloorOfWidth * coordinates.width(j));
    const double drift = drift_rel[static_cast<std::size_t>(j)] * scale / coordinates.width(j);
    drift_var(j) = drift * drift;
  }
  // The cross-covariance in the start's scaled coordinates (a shift of 1 moves q by q_scale).
  Eigen::VectorXd inv_scale(nb);
  for (int i = 0; i < coordinates.n_start_modes(); ++i) {
    inv_scale(2 * i) = 1.0 / coordinates.q_scale(i);
    inv_scale(2 * i + 1) = 1.0 / coordinates.v_scale(i);
  }
  const Eigen::MatrixXd cross = previous.param_end_cov * inv_scale.asDiagonal();
  // Conditioning on the start as the start prior holds it (its floor included, which only widens
  // the conditional).
  p.regression = cross * start_information;
  Eigen::MatrixXd cov = previous.param_cov - p.regression * cross.transpose();
  cov = 0.5 * (cov + cov.transpose());
  cov.diagonal() += drift_var;
  if (!cov.allFinite()) return std::nullopt;
  // Relative to the largest eigenvalue: a nearly singular prior would claim enormous information.
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(cov);
  if (eig.info() != Eigen::Success || !(eig.eigenvalues().minCoeff() > 1e-12 * eig.eigenvalues().maxCoeff()))
    return std::nullopt;
  p.covariance = cov;
  return p;
}

PoolingStep pooling_step(const ParameterPrior& prior, const Eigen::VectorXd& v, const Eigen::MatrixXd& cov) {
  const Eigen::MatrixXd H = prior.measurement();
  const Eigen::VectorXd y = prior.centre - H * v;
  const Eigen::MatrixXd S = H * cov * H.transpose() + prior.covariance;
  const Eigen::LDLT<Eigen::MatrixXd> ldlt(S);
  const Eigen::VectorXd w = ldlt.solve(y);
  PoolingStep step;
  step.innovation_chi2 = w.allFinite() ? y.dot(w) : std::numeric_limits<double>::infinity();
  step.v = v + cov * H.transpose() * w;
  return step;
}

double pooled_innovation_chi2(double pooled_data_cost_m2, const Eigen::VectorXd& pooled_v, const StartPrior& pooled,
                              double own_data_cost_m2, const Eigen::VectorXd& own_v, const StartPrior& own,
                              double data_var_m2) {
  return (pooled_data_cost_m2 - own_data_cost_m2) / data_var_m2 + pooled.cost(pooled_v) / pooled.noise_var_m2() -
         own.cost(own_v) / own.noise_var_m2();
}

}  // namespace tipforce::inversion
