#include "tipforce/detail/forward_setup.hpp"

#include <algorithm>
#include <cmath>

#include "tipforce/assert.hpp"
#include "tipforce/drive.hpp"

namespace tipforce::detail {

void check_forward_batch(const ForwardProblem& pb, const ForwardBatch& batch, int max_modes) {
  TIPFORCE_THROW_UNLESS(pb.modal && pb.step && pb.window, "forward problem is incomplete");
  const Window& w = *pb.window;
  const int M = pb.modal->n_modes(), N = w.n_samples(), S = batch.n_sets;
  TIPFORCE_THROW_UNLESS(M >= 1 && M <= max_modes, "too many modes");
  TIPFORCE_THROW_UNLESS(N >= 1 && S >= 1, "empty batch or window");
  TIPFORCE_THROW_UNLESS(pb.substeps >= 1 && pb.substeps <= 64, "substeps must be in [1, 64]");
  TIPFORCE_THROW_UNLESS(pb.step->n_modes == M &&
                            std::abs(pb.step->dt_s * pb.substeps - w.sample_period_s) <= 1e-12 * w.sample_period_s,
                        "step coefficients do not match the window's sample period / substeps");
  TIPFORCE_THROW_UNLESS(batch.params.size() == static_cast<std::size_t>(ParameterLayout(pb.model).n_full()) * S,
                        "parameter array has the wrong size");
  TIPFORCE_THROW_UNLESS(batch.initial.size() == 1 || batch.initial.size() == static_cast<std::size_t>(S),
                        "initial states: one shared or one per set");
  for (const ModalState& s : batch.initial)
    TIPFORCE_THROW_UNLESS(static_cast<int>(s.q.size()) == M && static_cast<int>(s.v.size()) == M,
                          "initial state has the wrong number of modes");
  if (w.drive.kind == DriveKind::sampled)
    TIPFORCE_THROW_UNLESS(static_cast<int>(w.drive.base_m.size()) == N && N >= 3,
                          "a sampled drive needs one base value per sample (and at least 3 samples)");
}

LaneForce make_lane_force(ForceModelKind model, const ForceParams& p) {
  LaneForce l;
  l.model = static_cast<int>(model);
  l.k = p.k_n_per_m;
  l.c = p.c_ns_per_m;
  l.h = p.h_m;
  l.big_k = (4.0 / 3.0) * p.e_star_pa * std::sqrt(std::fmax(p.radius_m, 0.0));
  l.hr6 = p.hamaker_j * p.radius_m / 6.0;
  l.a0 = p.a0_m;
  l.eta_sqrt_r = p.eta_pa_s * std::sqrt(std::fmax(p.radius_m, 0.0));
  l.f0 = p.a0_m > 0 ? l.hr6 / (p.a0_m * p.a0_m) : 0.0;
  return l;
}

LaneForce lane_force_of_set(ForceModelKind model, const ForwardBatch& batch, int set) {
  const ParameterLayout layout(model);
  return make_lane_force(model, FullParams(layout, batch.params, batch.n_sets, set).force_params());
}

TipStepResponse tip_step_response(const ModalModel& modal, const StepCoefficients& s) {
  TipStepResponse r;
  for (int i = 0; i < modal.n_modes(); ++i) {
    const double phi = modal.modes()[i].phi_tip;
    const double c = phi * phi / modal.modal_mass_kg();
    r.z_start += c * s.hq_start[i];
    r.z_end += c * s.hq_end[i];
    r.v_start += c * s.hv_start[i];
    r.v_end += c * s.hv_end[i];
  }
  return r;
}

ModeConstants make_mode_constants(const ModalModel& modal, const StepCoefficients& st) {
  TIPFORCE_DEMAND(modal.n_modes() <= kMaxModes && st.n_modes == modal.n_modes());
  ModeConstants k{};
  for (int i = 0; i < modal.n_modes(); ++i) {
    const Mode& m = modal.modes()[static_cast<std::size_t>(i)];
    const double c = m.phi_tip / modal.modal_mass_kg();
    k.a00[i] = st.a00[i];
    k.a01[i] = st.a01[i];
    k.a10[i] = st.a10[i];
    k.a11[i] = st.a11[i];
    k.cs_q[i] = c * st.hq_start[i];
    k.cs_v[i] = c * st.hv_start[i];
    k.ce_q[i] = c * st.hq_end[i];
    k.ce_v[i] = c * st.hv_end[i];
    k.phi[i] = m.phi_tip;
    k.gain[i] = modal.sensor_gain(i);
    k.gamma[i] = m.gamma;
    k.curv_q[i] = std::abs(m.phi_tip) * (1.0 + 2.0 * m.zeta) * m.omega_rad_per_s * m.omega_rad_per_s;
    k.curv_v[i] = std::abs(m.phi_tip) * (1.0 + 2.0 * m.zeta) * m.omega_rad_per_s;
    k.wq0[i] = st.wq0[i];
    k.wv0[i] = st.wv0[i];
    k.wqm[i] = st.wqm[i];
    k.wvm[i] = st.wvm[i];
    k.wq1[i] = st.wq1[i];
    k.wv1[i] = st.wv1[i];
  }
  k.tip = tip_step_response(modal, st);
  k.h_s = st.dt_s;
  return k;
}

const ModeConstants* StepLevels::get(const ModalModel& modal, const StepCoefficients& coarse) {
  const double omega1 = modal.modes()[0].omega_rad_per_s;
  if (modal_ != &modal || omega1_ != omega1 || n_modes_ != modal.n_modes() || h_s_ != coarse.dt_s) {
    levels_.assign(kSubstepLevels, ModeConstants{});
    levels_[0] = make_mode_constants(modal, coarse);
    for (int j = 1; j < kSubstepLevels; ++j)
      levels_[static_cast<std::size_t>(j)] = make_mode_constants(modal, make_step_coefficients(modal, coarse.dt_s / (1 << j)));
    modal_ = &modal;
    omega1_ = omega1;
    n_modes_ = modal.n_modes();
    h_s_ = coarse.dt_s;
  }
  return levels_.data();
}

ContactResolution contact_resolution(const ModalModel& modal, const ForwardProblem& problem) {
  const double rad_per_substep = problem.contact_rad_per_substep > 0 ? problem.contact_rad_per_substep
                                                                     : default_contact_rad_per_substep(problem.model);
  ContactResolution r;
  r.omega1_rad_per_s = modal.modes()[0].omega_rad_per_s;
  r.k_static_n_per_m = modal.static_stiffness_n_per_m();
  r.rad_per_substep = rad_per_substep;
  r.extrapolate = problem.extrapolate_contact.value_or(default_extrapolate_contact(problem.model));
  return r;
}

DriveFunction analytic_drive(const Window& w, const double dp[4]) {
  DriveFunction f;
  f.kind = static_cast<int>(w.drive.kind);
  for (int k = 0; k < 4; ++k) f.params[k] = dp[k];
  f.t0_s = w.t0_s;
  f.sample_period_s = w.sample_period_s;
  return f;
}

void make_shared_drive(const ModalModel& modal, const StepCoefficients& step, const Window& w, const double dp[4],
                       int substeps, SharedDrive& d) {
  const int m = modal.n_modes();
  const int ns = w.n_samples();
  const int n = ns * substeps;  // coarse steps
  const double dt = w.sample_period_s / substeps;
  d.fn = analytic_drive(w, dp);
  if (w.drive.kind == DriveKind::sampled) {
    TIPFORCE_DEMAND(static_cast<int>(w.drive.base_m.size()) == ns && ns >= 3);
    // Finite differences at the samples (one sample extrapolated past the end), interpolated
    // linearly in between.
    const auto& y = w.drive.base_m;
    const double ts = w.sample_period_s;
    d.ys.assign(static_cast<std::size_t>(ns) + 1, 0.0);
    d.vs.assign(d.ys.size(), 0.0);
    d.as.assign(d.ys.size(), 0.0);
    for (int i = 0; i < ns; ++i) d.ys[i] = y[i];
    d.ys[ns] = 2 * y[ns - 1] - y[ns - 2];
    for (int i = 0; i <= ns; ++i) {
      const int lo = i == 0 ? 0 : i - 1, hi = i == ns ? ns : i + 1;
      d.vs[i] = (d.ys[hi] - d.ys[lo]) / ((hi - lo) * ts);
      const int c = i == 0 ? 1 : (i == ns ? ns - 1 : i);
      d.as[i] = (d.ys[c + 1] - 2 * d.ys[c] + d.ys[c - 1]) / (ts * ts);
    }
    d.fn.n_samples = ns;
    d.fn.ys = d.ys.data();
    d.fn.vs = d.vs.data();
    d.fn.as = d.as.data();
  }
  d.y_m.resize(static_cast<std::size_t>(n) + 1);
  d.ydot_m_per_s.resize(static_cast<std::size_t>(n) + 1);
  std::vector<double> acc(static_cast<std::size_t>(n) + 1), acc_mid(static_cast<std::size_t>(n));
  for (int i = 0; i <= n; ++i) {
    const Motion b = d.fn.at(w.t0_s + i * dt);
    d.y_m[i] = b.y;
    d.ydot_m_per_s[i] = b.yd;
    acc[i] = b.ydd;
  }
  for (int i = 0; i < n; ++i) acc_mid[i] = d.fn.at(w.t0_s + (i + 0.5) * dt).ydd;
  const ModeConstants c = make_mode_constants(modal, step);
  d.dq.resize(static_cast<std::size_t>(n) * m);
  d.dv.resize(static_cast<std::size_t>(n) * m);
  StepDrive<kMaxModes, 1> inc;
  for (int i = 0; i < n; ++i) {
    drive_increment(c, m, acc[i], acc_mid[i], acc[i + 1], 0, inc);
    for (int k = 0; k < m; ++k) {
      d.dq[static_cast<std::size_t>(i) * m + k] = inc.dq[k][0];
      d.dv[static_cast<std::size_t>(i) * m + k] = inc.dv[k][0];
    }
  }
}

}  // namespace tipforce::detail
