// Exact per-mode discretisation over one sample period: the transition matrix and the responses to
// polynomial holds of the modal force, by Gauss-Legendre quadrature of e^{A (dt - s)} B s^k.
#include <unsupported/Eigen/MatrixFunctions>

#include "quadrature.hpp"
#include "tipforce/assert.hpp"
#include "tipforce/forward.hpp"

namespace tipforce {

StepCoefficients make_step_coefficients(const ModalModel& modal, double dt) {
  TIPFORCE_THROW_UNLESS(std::isfinite(dt) && dt > 0, "sample period must be positive");
  StepCoefficients c;
  c.dt_s = dt;
  c.n_modes = modal.n_modes();
  const auto& rule = detail::gauss_legendre_unit(64);
  for (const Mode& m : modal.modes()) {
    // In (q, v / omega) the matrix is well scaled; e^{A t} of the raw [[0, 1], [-w^2, -2 z w]]
    // loses relative accuracy in its small entries (1e-7 beside 1e6), which the high modes feel.
    const double w = m.omega_rad_per_s;
    Eigen::Matrix2d As;
    As << 0.0, w, -w, -2.0 * m.zeta * w;
    auto transition = [&](double t) {
      const Eigen::Matrix2d e = (As * t).exp();
      Eigen::Matrix2d phi;
      phi << e(0, 0), e(0, 1) / w, e(1, 0) * w, e(1, 1);
      return phi;
    };
    const Eigen::Matrix2d phi = transition(dt);
    c.a00.push_back(phi(0, 0));
    c.a01.push_back(phi(0, 1));
    c.a10.push_back(phi(1, 0));
    c.a11.push_back(phi(1, 1));
    // G_k = integral over s in [0, dt] of e^{A (dt - s)} [0 1]^T (s/dt)^k.
    Eigen::Vector2d g[3] = {Eigen::Vector2d::Zero(), Eigen::Vector2d::Zero(), Eigen::Vector2d::Zero()};
    for (std::size_t k = 0; k < rule.nodes.size(); ++k) {
      const double u = rule.nodes[k];
      const Eigen::Vector2d col = transition(dt * (1.0 - u)).col(1) * (rule.weights[k] * dt);
      g[0] += col;
      g[1] += col * u;
      g[2] += col * (u * u);
    }
    const Eigen::Vector2d start = g[0] - g[1], end = g[1];
    const Eigen::Vector2d w0 = 2 * g[2] - 3 * g[1] + g[0], wm = 4 * g[1] - 4 * g[2], w1 = 2 * g[2] - g[1];
    c.hq_start.push_back(start(0));
    c.hv_start.push_back(start(1));
    c.hq_end.push_back(end(0));
    c.hv_end.push_back(end(1));
    c.wq0.push_back(w0(0));
    c.wv0.push_back(w0(1));
    c.wqm.push_back(wm(0));
    c.wvm.push_back(wm(1));
    c.wq1.push_back(w1(0));
    c.wv1.push_back(w1(1));
  }
  return c;
}

}  // namespace tipforce
