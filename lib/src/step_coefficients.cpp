// Exact per-mode discretisation of one step: the transition matrices and the responses to the
// quadratic (Lagrange) hold of a modal force, by Gauss-Legendre quadrature of e^{A (t - s)} B s^k.
#include <unsupported/Eigen/MatrixFunctions>

#include <cstdio>
#include <optional>
#include <string>

#include "quadrature.hpp"
#include "tipforce/assert.hpp"
#include "tipforce/forward.hpp"

namespace tipforce {
namespace {

// One mode's exact linear update in physical units (q, v).
class ModeTransition {
 public:
  ModeTransition(double omega, double zeta) : omega_(omega) {
    // In (q, v / omega) the matrix is well scaled; e^{A t} of the raw [[0, 1], [-w^2, -2 z w]]
    // loses relative accuracy in its small entries (1e-7 beside 1e6), which the high modes feel.
    scaled_ << 0.0, omega, -omega, -2.0 * zeta * omega;
  }
  Eigen::Matrix2d at(double t) const {
    const Eigen::Matrix2d e = (scaled_ * t).exp();
    Eigen::Matrix2d phi;
    phi << e(0, 0), e(0, 1) / omega_, e(1, 0) * omega_, e(1, 1);
    return phi;
  }
  // g_p = integral over s in [0, t] of e^{A (t - s)} [0 1]^T (s / t)^p, p < kHoldPoints.
  std::array<Eigen::Vector2d, kHoldPoints> moments(double t) const {
    static const detail::QuadratureRule& rule = detail::gauss_legendre_unit(64);
    std::array<Eigen::Vector2d, kHoldPoints> g;
    for (auto& x : g) x.setZero();
    for (std::size_t k = 0; k < rule.nodes.size(); ++k) {
      const double u = rule.nodes[k];
      const Eigen::Vector2d col = at(t * (1.0 - u)).col(1) * (rule.weights[k] * t);
      double up = 1.0;
      for (int p = 0; p < kHoldPoints; ++p, up *= u) g[p] += col * up;
    }
    return g;
  }

 private:
  double omega_;
  Eigen::Matrix2d scaled_;
};

// The monomial coefficients of the Lagrange basis through the hold's points: l_k(u) = sum_p c[k][p] u^p.
using Basis = std::array<std::array<double, kHoldPoints>, kHoldPoints>;
Basis lagrange_basis() {
  Basis c{};
  for (int k = 0; k < kHoldPoints; ++k) {
    std::array<double, kHoldPoints> poly{};
    poly[0] = 1.0;
    int degree = 0;
    for (int m = 0; m < kHoldPoints; ++m) {
      if (m == k) continue;
      const double scale = 1.0 / (kHoldNodes[k] - kHoldNodes[m]);
      // poly *= (u - u_m) * scale
      for (int p = degree + 1; p >= 0; --p)
        poly[p] = ((p > 0 ? poly[p - 1] : 0.0) - kHoldNodes[m] * poly[p]) * scale;
      ++degree;
    }
    c[k] = poly;
  }
  return c;
}

// The responses at tau dt to the Lagrange basis on [0, dt], from the moments g_p of (s / (tau dt))^p
// over [0, tau dt]: u^p = tau^p (s / (tau dt))^p with u = s / dt.
std::array<Eigen::Vector2d, kHoldPoints> lagrange_responses(const std::array<Eigen::Vector2d, kHoldPoints>& g,
                                                            double tau, const Basis& c) {
  std::array<Eigen::Vector2d, kHoldPoints> r;
  for (int k = 0; k < kHoldPoints; ++k) {
    r[k].setZero();
    double tp = 1.0;
    for (int p = 0; p < kHoldPoints; ++p, tp *= tau) r[k] += c[k][p] * tp * g[p];
  }
  return r;
}

}  // namespace

std::optional<std::string> step_problem(const ModalModel& modal, double dt) {
  // The steps back (a step undone, the free path at the inner points from the end) grow as
  // e^{zeta omega h}: a heavily damped high mode overflows them at a long step (32 modes at Q 0.5
  // and 2e-6 s: e^891), and every answer would be NaN. Up to ~e^690 they are used as they are
  // (32 modes at Q 0.7 and 2e-6 s, e^636, within 5e-9 of the reference).
  for (const Mode& m : modal.modes()) {
    const ModeTransition tr(m.omega_rad_per_s, m.zeta);
    for (const Eigen::Matrix2d& back : {tr.at(-dt), tr.at(-(1.0 - kHoldNodes[1]) * dt)}) {
      if (back.allFinite() && back.cwiseAbs().maxCoeff() < 1e300) continue;
      char what[256];
      std::snprintf(what, sizeof what,
                    "the mode at %.4g Hz (Q %.3g) decays by e^-%.0f within a step of %.3g s, more than the solver "
                    "can step back: model fewer modes or sample faster",
                    m.frequency_hz, m.quality_factor, m.zeta * m.omega_rad_per_s * dt, dt);
      return std::string(what);
    }
  }
  return std::nullopt;
}

StepCoefficients make_step_coefficients(const ModalModel& modal, double dt) {
  TIPFORCE_THROW_UNLESS(std::isfinite(dt) && dt > 0, "sample period must be positive");
  const std::optional<std::string> problem = step_problem(modal, dt);
  TIPFORCE_THROW_UNLESS(!problem, problem.value_or(""));
  StepCoefficients c;
  c.dt_s = dt;
  c.n_modes = modal.n_modes();
  auto push = [](const Eigen::Matrix2d& m, std::vector<double>& x00, std::vector<double>& x01, std::vector<double>& x10,
                 std::vector<double>& x11) {
    x00.push_back(m(0, 0));
    x01.push_back(m(0, 1));
    x10.push_back(m(1, 0));
    x11.push_back(m(1, 1));
  };
  const Basis basis = lagrange_basis();
  for (const Mode& m : modal.modes()) {
    const ModeTransition tr(m.omega_rad_per_s, m.zeta);
    push(tr.at(dt), c.a00, c.a01, c.a10, c.a11);
    push(tr.at(-dt), c.u00, c.u01, c.u10, c.u11);
    const auto end = lagrange_responses(tr.moments(dt), 1.0, basis);
    for (int k = 0; k < kHoldPoints; ++k) {
      c.end_q[k].push_back(end[k](0));
      c.end_v[k].push_back(end[k](1));
    }
    for (int n = 0; n + 2 < kHoldPoints; ++n) {
      const double tau = kHoldNodes[n + 1];
      const Eigen::Matrix2d back = tr.at(-(1.0 - tau) * dt);
      for (double x : {back(0, 0), back(0, 1), back(1, 0), back(1, 1)}) c.back[n].push_back(x);
      const auto at = lagrange_responses(tr.moments(tau * dt), tau, basis);
      for (int k = 0; k < kHoldPoints; ++k) {
        c.at_q[n][k].push_back(at[k](0));
        c.at_v[n][k].push_back(at[k](1));
      }
    }
  }
  return c;
}

}  // namespace tipforce
