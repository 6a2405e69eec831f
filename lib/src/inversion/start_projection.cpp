#include "inversion/start_projection.hpp"

#include <algorithm>
#include <cmath>

namespace tipforce::inversion {
namespace {

Eigen::VectorXd residual_of(const Window& w, const std::vector<double>& signal, std::size_t set) {
  const int N = w.n_samples();
  Eigen::VectorXd res(N);
  for (int n = 0; n < N; ++n) res(n) = w.deflection_m[n] - signal[set * N + n];
  return res;
}

}  // namespace

StartProjection::StartProjection(const Eigen::MatrixXd& unit_decay, const Coordinates& coordinates)
    : decay_(unit_decay) {
  for (int i = 0; i < coordinates.n_start_modes(); ++i) {
    decay_.col(2 * i) *= coordinates.q_scale(i);
    decay_.col(2 * i + 1) *= coordinates.v_scale(i);
  }
  const auto N = decay_.rows(), n_basis = decay_.cols();
  basis_ = decay_.householderQr().householderQ() * Eigen::MatrixXd::Identity(N, n_basis);
}

double StartProjection::projected_cost(double cost, const Eigen::VectorXd& residual) const {
  return std::max(0.0, cost - (basis_.transpose() * residual).squaredNorm());
}

Eigen::VectorXd StartProjection::best_shift(const Eigen::VectorXd& residual) const {
  return decay_.colPivHouseholderQr().solve(residual);
}

std::vector<double> SearchCost::costs(std::span<const Point> points) {
  if (projection_ == nullptr) return evaluator_.evaluate(points, false, Resolution::search).cost;
  Evaluation e = evaluator_.evaluate(points, true, Resolution::search);
  for (std::size_t s = 0; s < points.size(); ++s) {
    if (!std::isfinite(e.cost[s])) continue;
    e.cost[s] = projection_->projected_cost(e.cost[s], residual_of(window_, e.signal, s));
  }
  return e.cost;
}

Point with_best_start_shift(BatchEvaluator& evaluator, const Window& window, const StartProjection& projection,
                            const Point& incumbent, double& cost) {
  const Evaluation e = evaluator.evaluate(std::span<const Point>(&incumbent, 1), true);
  const Eigen::VectorXd c = projection.best_shift(residual_of(window, e.signal, 0));
  Point shifted = incumbent;
  for (int i = 0; i < static_cast<int>(c.size()) / 2; ++i) {
    shifted.dq[i] = c(2 * i);
    shifted.dv[i] = c(2 * i + 1);
  }
  const double shifted_cost = evaluator.evaluate(std::span<const Point>(&shifted, 1), false).cost[0];
  cost = std::min(shifted_cost, e.cost[0]);
  return shifted_cost < e.cost[0] ? shifted : incumbent;
}

}  // namespace tipforce::inversion
