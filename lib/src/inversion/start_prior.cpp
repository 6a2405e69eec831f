#include "inversion/start_prior.hpp"

#include <algorithm>

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
    : information_(std::move(information)), noise_var_m2_(noise_var_m2) {
  const int nb = static_cast<int>(information_.rows());
  hessian_ = Eigen::MatrixXd::Zero(n_packed, n_packed);
  hessian_.bottomRightCorner(nb, nb) = noise_var_m2_ * information_;
}

double StartPrior::cost(const Eigen::VectorXd& packed) const {
  if (!present()) return 0.0;
  const Eigen::VectorXd s = packed.tail(information_.rows());
  return noise_var_m2_ * s.dot(information_ * s);
}

}  // namespace tipforce::inversion
