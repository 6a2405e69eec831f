// The free steady state of the modal model under a sine base motion (forward.hpp): where the
// solver's sine drive starts, and what an unknown start is estimated from.
#include <complex>
#include <numbers>

#include "tipforce/forward.hpp"

namespace tipforce {

ModalState linear_steady_state(const ModalModel& modal, double a, double f_hz, double phase, double t) {
  ModalState s = ModalState::rest(modal.n_modes());
  const double W = 2 * std::numbers::pi * f_hz;
  const std::complex<double> e = std::polar(1.0, W * t + phase);
  for (int i = 0; i < modal.n_modes(); ++i) {
    const Mode& m = modal.modes()[i];
    // q'' + 2 zeta w q' + w^2 q = -gamma y'' = gamma a W^2 sin(W t + phase)
    const std::complex<double> h = 1.0 / std::complex<double>(m.omega_rad_per_s * m.omega_rad_per_s - W * W,
                                                              2 * m.zeta * m.omega_rad_per_s * W);
    const std::complex<double> qc = m.gamma * a * W * W * h * e;
    s.q[i] = qc.imag();
    s.v[i] = (std::complex<double>(0, W) * qc).imag();
  }
  return s;
}

}  // namespace tipforce
