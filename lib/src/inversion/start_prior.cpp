#include "inversion/start_prior.hpp"

#include <algorithm>
#include <limits>

#include "tipforce/assert.hpp"

namespace tipforce::inversion {

Eigen::MatrixXd start_prior_information(const Eigen::MatrixXd& end_cov_phys, const Coordinates& coordinates,
                                        double floor_rel) {
  const int nb = coordinates.n_start_block();
  Eigen::VectorXd scale(nb);
  for (int i = 0; i < coordinates.n_start_modes(); ++i) {
    scale(2 * i) = coordinates.q_scale(i);
    scale(2 * i + 1) = coordinates.v_scale(i);
  }
  const Eigen::MatrixXd cov = scale.cwiseInverse().asDiagonal() * end_cov_phys * scale.cwiseInverse().asDiagonal();
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(0.5 * (cov + cov.transpose()));
  // The floor's own floor only keeps a zero floor_rel from dividing by zero.
  const double floor_var = std::max(floor_rel * floor_rel, 1e-300);
  const Eigen::VectorXd var = eig.eigenvalues().cwiseMax(0.0).array() + floor_var;
  return eig.eigenvectors() * var.cwiseInverse().asDiagonal() * eig.eigenvectors().transpose();
}

StartPrior::StartPrior(Eigen::MatrixXd information, double noise_var_m2, int n_packed)
    : information_(std::move(information)), noise_var_m2_(noise_var_m2), centre_(Eigen::VectorXd::Zero(n_packed)) {
  const int nb = static_cast<int>(information_.rows());
  packed_information_ = Eigen::MatrixXd::Zero(n_packed, n_packed);
  packed_information_.bottomRightCorner(nb, nb) = information_;
  hessian_ = noise_var_m2_ * packed_information_;
}

StartPrior StartPrior::with_parameters(const Eigen::MatrixXd& parameter_information,
                                       const Eigen::VectorXd& parameter_centre) const {
  TIPFORCE_DEMAND(present() && parameter_information.rows() == hessian_.rows() &&
                  parameter_information.cols() == hessian_.cols() && parameter_centre.size() <= centre_.size());
  StartPrior pooled = *this;
  pooled.packed_information_ += parameter_information;
  pooled.hessian_ = noise_var_m2_ * pooled.packed_information_;
  pooled.centre_.head(parameter_centre.size()) = parameter_centre;
  pooled.pools_ = true;
  return pooled;
}

double StartPrior::cost(const Eigen::VectorXd& packed) const {
  if (!present()) return 0.0;
  if (pools_) {
    const Eigen::VectorXd d = packed - centre_;
    return d.dot(hessian_ * d);
  }
  const Eigen::VectorXd s = packed.tail(information_.rows());
  return noise_var_m2_ * s.dot(information_ * s);
}

double start_conflict_chi2(const Linearisation& lin, const StartPrior& prior, const Eigen::VectorXd& v, int m) {
  const int nb = static_cast<int>(prior.information().rows()), np = static_cast<int>(v.size());
  const double var = prior.noise_var_m2();
  if (nb == 0 || !(var > 0) || lin.J.cols() != np || lin.r.size() != lin.J.rows()) return 0.0;
  const Eigen::VectorXd s = v.tail(nb);
  const double penalty = s.dot(prior.information() * s);
  // The data's Hessian in chi-square units, with the bounds' information on the parameters (as
  // in the covariance), so that an unknown the window hardly moves does not make it singular.
  Eigen::MatrixXd A = lin.J.transpose() * lin.J / var;
  for (int j = 0; j < m; ++j) A(j, j) += kBoundsInformation;
  // The pull on the start alone: the parameters sit at their optimum (their gradient is zero
  // away from the bounds, and at a bound the fit may not move them on).
  Eigen::VectorXd g = Eigen::VectorXd::Zero(np);
  g.tail(nb) = (lin.J.transpose() * lin.r).tail(nb) / var;
  const Eigen::VectorXd step = A.ldlt().solve(g);
  const double gain = step.allFinite() ? g.dot(step) : std::numeric_limits<double>::infinity();
  return penalty + std::max(0.0, gain);
}

}  // namespace tipforce::inversion
