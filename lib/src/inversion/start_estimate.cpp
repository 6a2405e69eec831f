#include "inversion/start_estimate.hpp"

#include <algorithm>
#include <limits>

#include <Eigen/Dense>

#include "tipforce/drive.hpp"
#include "tipforce/forward.hpp"

namespace tipforce::inversion {

ModalState estimate_unknown_start(const ModalModel& modal, const Window& w, const InversionOptions& options) {
  const int M = modal.n_modes(), N = w.n_samples();
  ModalState init = ModalState::rest(M);
  if (w.drive.kind != DriveKind::sampled)
    init = linear_steady_state(modal, w.drive.amplitude_m, w.drive.frequency_hz, w.drive.phase_rad, w.t0_s);
  const double period = 1.0 / modal.modes()[0].frequency_hz;
  const int k = std::clamp(static_cast<int>(period * options.start_fit_period_fraction / w.sample_period_s), 3, N);
  if (k < 3) return init;
  Eigen::MatrixXd A(k, 3);
  Eigen::VectorXd b(k);
  for (int i = 0; i < k; ++i) {
    const double t = i * w.sample_period_s;
    A.row(i) << 1.0, t, t * t;
    b(i) = w.deflection_m[i];
  }
  const Eigen::Vector3d c = A.colPivHouseholderQr().solve(b);
  double s0 = 0, s1 = 0;
  for (int i = 1; i < M; ++i) {
    s0 += modal.sensor_gain(i) * init.q[i];
    s1 += modal.sensor_gain(i) * init.v[i];
  }
  init.q[0] = (c(0) - s0) / modal.sensor_gain(0);
  init.v[0] = (c(1) - s1) / modal.sensor_gain(0);
  return init;
}

std::optional<double> tip_reach_m(const ModalModel& modal, const Window& w) {
  if (modal.sensor() != Sensor::displacement || w.deflection_m.empty()) return std::nullopt;
  double reach = -std::numeric_limits<double>::infinity();
  for (int n = 0; n < w.n_samples(); ++n) {
    const double y = w.drive.kind == DriveKind::sampled
                         ? w.drive.base_m[static_cast<std::size_t>(n)]
                         : base_motion(w.drive.kind, w.drive.amplitude_m, w.drive.frequency_hz, w.drive.phase_rad,
                                       w.drive.chirp_hz_per_s, w.t0_s + n * w.sample_period_s)
                               .y_m;
    reach = std::max(reach, y + w.deflection_m[static_cast<std::size_t>(n)]);
  }
  return reach;
}

}  // namespace tipforce::inversion
