#include "inversion/coordinates.hpp"

#include <cmath>

namespace tipforce::inversion {

Coordinates::Coordinates(const ParameterSpace& space, const ModalModel& modal, double signal_scale_m, bool start_free)
    : m_(space.n_unknowns()),
      n_modes_(std::min(kStartModes, modal.n_modes())),
      start_free_(start_free),
      lo_(space.lower()),
      hi_(space.upper()) {
  for (int i = 0; i < n_modes_; ++i) {
    q_scale_[i] = signal_scale_m / std::abs(modal.modes()[i].phi_tip);
    v_scale_[i] = q_scale_[i] * modal.modes()[i].omega_rad_per_s;
  }
}

std::vector<double> Coordinates::values(const std::vector<double>& x) const {
  std::vector<double> u(static_cast<std::size_t>(m_));
  for (int j = 0; j < m_; ++j) u[j] = lo_[j] + x[j] * (hi_[j] - lo_[j]);
  return u;
}

Point Coordinates::centre() const {
  Point p;
  p.x.assign(static_cast<std::size_t>(m_), 0.5);
  return p;
}

Eigen::VectorXd Coordinates::pack(const Point& p) const {
  Eigen::VectorXd v(n_packed());
  for (int j = 0; j < m_; ++j) v(j) = p.x[j];
  for (int i = 0; i < n_start_unknowns() / 2; ++i) {
    v(m_ + 2 * i) = p.dq[i];
    v(m_ + 2 * i + 1) = p.dv[i];
  }
  return v;
}

Point Coordinates::unpack(const Eigen::VectorXd& v) const {
  Point p;
  p.x.resize(static_cast<std::size_t>(m_));
  for (int j = 0; j < m_; ++j) p.x[j] = clamp01(v(j));
  for (int i = 0; i < n_start_unknowns() / 2; ++i) {
    p.dq[i] = v(m_ + 2 * i);
    p.dv[i] = v(m_ + 2 * i + 1);
  }
  return p;
}

ModalState Coordinates::shifted(const ModalState& start, const Point& p) const {
  ModalState s = start;
  for (int i = 0; i < n_modes_; ++i) {
    s.q[i] += p.dq[i] * q_scale_[i];
    s.v[i] += p.dv[i] * v_scale_[i];
  }
  return s;
}

}  // namespace tipforce::inversion
