#include "inversion/covariance.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include "cpu_step.hpp"
#include "inversion/coordinates.hpp"

namespace tipforce::inversion {

std::optional<Eigen::MatrixXd> inverse_spd(const Eigen::MatrixXd& a, double min_rel_eigenvalue) {
  const Eigen::VectorXd d = a.diagonal();
  if (!a.allFinite() || !(d.array() > 0).all()) return std::nullopt;
  const Eigen::VectorXd scale = d.cwiseSqrt().cwiseInverse();
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(scale.asDiagonal() * a * scale.asDiagonal());
  const Eigen::VectorXd ev = eig.eigenvalues();
  if (!(ev.minCoeff() > min_rel_eigenvalue * ev.maxCoeff())) return std::nullopt;
  return Eigen::MatrixXd(scale.asDiagonal() * (eig.eigenvectors() * ev.cwiseInverse().asDiagonal() * eig.eigenvectors().transpose()) *
                         scale.asDiagonal());
}

double hac_inflation(const Eigen::VectorXd& r, int lags) {
  const int N = static_cast<int>(r.size());
  const double r0 = r.squaredNorm();
  if (!(r0 > 0) || lags <= 0) return 1.0;
  // Lags at or beyond the window's end have no products (their terms are zero; the weights keep lags).
  const int within = std::min(lags, N - 1);
  std::vector<double> products(static_cast<std::size_t>(std::max(within, 0)));
  if (within > 0) cpu::lag_products(r.data(), N, within, products.data());
  double tau = 1.0;
  for (int k = 1; k <= within; ++k) {
    const double rho = products[static_cast<std::size_t>(k - 1)] / r0;
    tau += 2.0 * (1.0 - static_cast<double>(k) / (lags + 1)) * rho;  // Bartlett weights
  }
  return std::max(1.0, tau);
}

Uncertainty posterior_uncertainty(const Eigen::MatrixXd& J, const Eigen::VectorXd& r, double cost,
                                  const Eigen::MatrixXd& prior_information, const std::vector<double>& widths,
                                  const std::vector<std::string>& names, const std::vector<double>& x,
                                  const InversionOptions& opt, double min_noise_var_m2) {
  const int m = static_cast<int>(widths.size()), N = static_cast<int>(J.rows()), np = static_cast<int>(J.cols());
  Uncertainty u;
  u.sigma.assign(static_cast<std::size_t>(m), std::numeric_limits<double>::infinity());
  u.determined.assign(static_cast<std::size_t>(m), false);
  u.covariance = Eigen::MatrixXd::Constant(m, m, std::numeric_limits<double>::infinity());
  // Residual variance, inflated by the residuals' autocorrelation (a HAC correction): white
  // noise leaves it as it is, while structure the model cannot follow (a start inherited from
  // the previous pixel's fit, a model that is slightly wrong) shrinks the number of independent
  // samples and must widen the uncertainty rather than bias it silently.
  double s2 = cost / (N - np);
  s2 *= hac_inflation(r, std::min(static_cast<int>(N * opt.hac_max_lag_fraction), opt.hac_max_lags));
  // A window fitted below the forward model's own error (data from the same solver) does not
  // know its unknowns better than the model does: without the floor its sigma, the prior it hands
  // on and the chi-squares measured in its variance came from rounding, and scattered by decades
  // from one window to the next.
  s2 = std::max(s2, min_noise_var_m2);
  // Posterior information: this window's data plus the prior (a Kalman update). The
  // prior can only add information, so a continued window is never less certain than the same
  // window with its start unknown: what is inherited is bounded by construction.
  Eigen::MatrixXd info = J.transpose() * J / s2;
  if (prior_information.rows() == np && prior_information.cols() == np) info += prior_information;
  const auto data_cov = inverse_spd(info, opt.singular_rel_eigenvalue);
  u.identifiable = data_cov.has_value();
  if (data_cov) u.data_covariance = *data_cov;
  if (!u.identifiable) u.notes += "parameters not identifiable from this window (singular Gauss-Newton matrix); ";
  // The bounds are prior knowledge too: a uniform distribution over them has variance 1/12 in
  // the normalised coordinates. Added as Gaussian information, it keeps an unknown the window
  // does not determine (k of a contact so light or so stiff that it hardly moves the signal)
  // from a linearised sigma thousands of times its bounds, and adds next to nothing where the
  // data do determine it.
  for (int j = 0; j < m; ++j) info(j, j) += kBoundsInformation;
  if (const auto cov_x = inverse_spd(info, opt.singular_rel_eigenvalue)) {
    // Normalised unknowns (+ start shifts); the start is marginalised by taking the block.
    u.noise_var_m2 = s2;
    u.full_covariance = *cov_x;
    Eigen::MatrixXd cov = cov_x->topLeftCorner(m, m);
    for (int i = 0; i < m; ++i)
      for (int j = 0; j < m; ++j) cov(i, j) *= widths[i] * widths[j];
    u.covariance = cov;
    for (int j = 0; j < m; ++j) u.sigma[j] = std::sqrt(std::max(cov(j, j), 0.0));
    for (int j = 0; j < m; ++j) {
      u.determined[j] = u.identifiable && std::sqrt((*cov_x)(j, j)) <= opt.undetermined_sigma_fraction / std::sqrt(kBoundsInformation);
      if (u.identifiable && !u.determined[j])
        u.notes += names[j] + " barely determined by this window (sigma near the spread of its bounds); ";
    }
    for (int i = 0; i < m; ++i)
      for (int j = i + 1; j < m; ++j) {
        const double corr = cov(i, j) / std::sqrt(cov(i, i) * cov(j, j));
        if (std::abs(corr) > opt.trade_off_correlation)
          u.notes += names[i] + " and " + names[j] + " trade off (correlation " + std::to_string(corr) + "); ";
      }
  }
  for (int j = 0; j < m; ++j)
    if (at_bound(x[j], opt.at_bound_tolerance)) u.notes += names[j] + " at its bound; ";
  return u;
}

}  // namespace tipforce::inversion
