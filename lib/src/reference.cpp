// The independent reference: odeint's adaptive Dormand-Prince on the modal ODEs, integrated as a
// hybrid system. Within a segment the contact branch is frozen and its force law (SPEC section 1,
// force_model.cpp, wherever the state is inside the branch's region) is continued smoothly past
// the region's edge, so every step sees a smooth right-hand side and the dense output is accurate;
// the switch is located by bisection on that dense output and the integration restarted there
// on the other branch.
#include "tipforce/reference.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <numbers>

#include <boost/numeric/odeint.hpp>

#include "tipforce/assert.hpp"
#include "sampled_base.hpp"
#include "tipforce/detail/forward_step.hpp"
#include "tipforce/drive.hpp"
#include "tipforce/parameter_layout.hpp"

namespace tipforce {
namespace {

namespace odeint = boost::numeric::odeint;
using State = std::vector<double>;

// The modal ODEs in scaled variables (q, v / omega_1) so that both halves have units of length.
class ModalOde {
 public:
  ModalOde(const ModalModel& modal, ForceModelKind model, const Window& w, std::span<const double> full)
      : modal_(modal), model_(model), w_(w), p_(force_params_from(model, full)) {
    const auto dp = FullParams(ParameterLayout(model), full).drive();
    std::copy(dp.begin(), dp.end(), drive_);
    vscale_ = modal.modes()[0].omega_rad_per_s;
    if (w.drive.kind == DriveKind::sampled) sampled_ = detail::make_sampled_base(w.drive.base_m, w.sample_period_s);
  }
  int m() const { return modal_.n_modes(); }
  double vscale() const { return vscale_; }

  BaseMotion base(double t) const {
    if (w_.drive.kind != DriveKind::sampled)
      return base_motion(w_.drive.kind, drive_[0], drive_[1], drive_[2], drive_[3], t);
    // Sampled: the samples read as the forward solver reads them (what they say between the
    // samples is a definition, not a scheme to check).
    detail::DriveFunction fn;  // built per call: a copy of this object keeps no pointer into another
    fn.kind = static_cast<int>(DriveKind::sampled);
    fn.t0_s = w_.t0_s;
    fn.sample_period_s = w_.sample_period_s;
    fn.n_samples = static_cast<int>(w_.drive.base_m.size());
    fn.ys = sampled_.y_m.data();
    fn.vs = sampled_.yd_m_per_s.data();
    fn.as = sampled_.ydd_m_per_s2.data();
    const detail::Motion m = fn.at(t);
    return {m.y, m.yd, m.ydd};
  }
  void tip(const State& x, double t, double& z, double& zd) const {
    const BaseMotion b = base(t);
    z = b.y_m;
    zd = b.ydot_m_per_s;
    for (int i = 0; i < m(); ++i) {
      z += modal_.modes()[i].phi_tip * x[i];
      zd += modal_.modes()[i].phi_tip * x[m() + i] * vscale_;
    }
  }
  // > 0 inside the contact region (where the force law's repulsive branch applies).
  double contact_switch(const State& x, double t) const {
    double z, zd;
    tip(x, t, z, zd);
    const double delta = z - p_.h_m;
    switch (model_) {
      case ForceModelKind::none: return -1.0;
      case ForceModelKind::kelvin_voigt: return std::min(delta, delta + p_.c_ns_per_m / p_.k_n_per_m * zd);
      case ForceModelKind::dmt:
      case ForceModelKind::dmt_viscous: return delta + p_.a0_m;
      default: return delta;
    }
  }
  void set_branch(bool in_contact) { in_contact_ = in_contact; }
  bool branch() const { return in_contact_; }
  // The force law of the frozen branch: SPEC's law inside its region, its smooth continuation outside.
  double force(const State& x, double t) const {
    double z, zd;
    tip(x, t, z, zd);
    const bool inside = (contact_switch(x, t) > 0) == in_contact_;
    if (inside) return tip_sample_force_n(model_, p_, z, zd);
    const double delta = z - p_.h_m;
    const double kr = (4.0 / 3.0) * p_.e_star_pa * std::sqrt(p_.radius_m);
    switch (model_) {
      case ForceModelKind::none: return 0.0;
      case ForceModelKind::spring: return in_contact_ ? -p_.k_n_per_m * delta : 0.0;
      case ForceModelKind::kelvin_voigt:
        return in_contact_ ? -p_.k_n_per_m * delta - p_.c_ns_per_m * zd : 0.0;
      case ForceModelKind::hertz: return in_contact_ ? -kr * delta * std::sqrt(std::abs(delta)) : 0.0;
      case ForceModelKind::dmt:
      case ForceModelKind::dmt_viscous: {
        const double hr6 = p_.hamaker_j * p_.radius_m / 6.0;
        const double pen = delta + p_.a0_m;
        if (!in_contact_) {
          const double d = p_.h_m - z;
          return hr6 / (d * d);
        }
        double f = hr6 / (p_.a0_m * p_.a0_m) - kr * pen * std::sqrt(std::abs(pen));
        if (model_ == ForceModelKind::dmt_viscous)
          f -= p_.eta_pa_s * std::sqrt(p_.radius_m * std::abs(pen)) * zd;
        return f;
      }
    }
    return 0.0;
  }
  void operator()(const State& x, State& dxdt, double t) const {
    const double f = force(x, t);
    const double acc = base(t).yddot_m_per_s2;
    const double mu_l = modal_.modal_mass_kg();
    for (int i = 0; i < m(); ++i) {
      const Mode& md = modal_.modes()[i];
      const double q = x[i], v = x[m() + i] * vscale_;
      dxdt[i] = v;
      const double a = -2 * md.zeta * md.omega_rad_per_s * v - md.omega_rad_per_s * md.omega_rad_per_s * q -
                       md.gamma * acc + md.phi_tip * f / mu_l;
      dxdt[m() + i] = a / vscale_;
    }
  }
  double signal(const State& x) const {
    double s = 0;
    for (int i = 0; i < m(); ++i) s += modal_.sensor_gain(i) * x[i];
    return s;
  }

 private:
  const ModalModel& modal_;
  ForceModelKind model_;
  const Window& w_;
  ForceParams p_;
  double drive_[4];
  double vscale_;
  bool in_contact_ = false;
  detail::SampledBase sampled_;  // a sampled drive's samples, differences and ghosts
};

State pack(const ModalOde& ode, const ModalState& s) {
  State x(2 * static_cast<std::size_t>(ode.m()));
  for (int i = 0; i < ode.m(); ++i) {
    x[i] = s.q[i];
    x[ode.m() + i] = s.v[i] / ode.vscale();
  }
  return x;
}
ModalState unpack(const ModalOde& ode, const State& x) {
  ModalState s = ModalState::rest(ode.m());
  for (int i = 0; i < ode.m(); ++i) {
    s.q[i] = x[i];
    s.v[i] = x[ode.m() + i] * ode.vscale();
  }
  return s;
}

}  // namespace

ReferenceResult reference_simulate(const ModalModel& modal, ForceModelKind model, const Window& w,
                                   std::span<const double> full, const ModalState& initial,
                                   const ReferenceOptions& opt) {
  TIPFORCE_THROW_UNLESS(!window_problem(w).has_value() || w.n_samples() > 0, "bad window");
  ModalOde ode(modal, model, w, full);
  const int n = w.n_samples();
  const double dt = w.sample_period_s;
  ReferenceResult out;
  out.signal.resize(static_cast<std::size_t>(n));
  out.force_n.resize(static_cast<std::size_t>(n));
  out.tip_z_m.resize(static_cast<std::size_t>(n));

  State x = pack(ode, initial);
  double t = w.t0_s;
  const double t_end = w.t0_s + n * dt;
  auto stepper = odeint::make_dense_output(opt.abs_tol, opt.rel_tol, 0.5 * dt, odeint::runge_kutta_dopri5<State>());
  stepper.initialize(x, t, 0.05 * dt);
  int next = 0;  // next sample to record
  State xs(x.size());
  auto record_until = [&](double t_hi, auto&& state_at) {
    while (next < n && w.t0_s + next * dt <= t_hi) {
      const double ts = w.t0_s + next * dt;
      state_at(ts, xs);
      out.signal[next] = ode.signal(xs);
      out.force_n[next] = ode.force(xs, ts);
      double zd;
      ode.tip(xs, ts, out.tip_z_m[next], zd);
      ++next;
    }
  };
  ode.set_branch(ode.contact_switch(x, t) > 0);
  record_until(t, [&](double, State& s) { s = x; });
  State xm(x.size());
  while (stepper.current_time() < t_end - 1e-9 * dt) {
    const double t_old = stepper.current_time();
    stepper.do_step(std::cref(ode));
    const double t_new = stepper.current_time();
    const bool in_new = ode.contact_switch(stepper.current_state(), t_new) > 0;
    if (in_new != ode.branch()) {
      // The dense output is smooth on the frozen branch: bisect it for the switch, record up to
      // there, then restart on the other branch.
      double lo = t_old, hi = t_new;
      for (int it = 0; it < 80 && hi - lo > 1e-17 * std::abs(hi) + 1e-24; ++it) {
        const double mid = 0.5 * (lo + hi);
        stepper.calc_state(mid, xm);
        ((ode.contact_switch(xm, mid) > 0) == ode.branch() ? lo : hi) = mid;
      }
      record_until(hi, [&](double ts, State& s) { stepper.calc_state(ts, s); });
      stepper.calc_state(hi, xm);
      ode.set_branch(!ode.branch());
      stepper.initialize(xm, hi, std::max(1e-4 * dt, std::min(0.01 * dt, t_end - hi)));
      continue;
    }
    record_until(std::min(t_new, t_end), [&](double ts, State& s) { stepper.calc_state(ts, s); });
  }
  State xe(x.size());
  stepper.calc_state(t_end, xe);
  out.end_state = unpack(ode, xe);
  return out;
}

std::vector<double> odeint_rk4_simulate(const ModalModel& modal, ForceModelKind model, const Window& w,
                                        std::span<const double> full, const ModalState& initial) {
  ModalOde ode(modal, model, w, full);
  odeint::runge_kutta4<State> rk4;
  State x = pack(ode, initial);
  std::vector<double> signal(static_cast<std::size_t>(w.n_samples()));
  double t = w.t0_s;
  for (int i = 0; i < w.n_samples(); ++i) {
    signal[i] = ode.signal(x);
    ode.set_branch(ode.contact_switch(x, t) > 0);  // no event handling: the law as it stands
    rk4.do_step(std::cref(ode), x, t, w.sample_period_s);
    t += w.sample_period_s;
  }
  return signal;
}

double relative_l2_error(std::span<const double> signal, std::span<const double> reference) {
  TIPFORCE_THROW_UNLESS(signal.size() >= reference.size(), "relative_l2_error: the signal is shorter than the reference");
  double num = 0, den = 0;
  for (std::size_t n = 0; n < reference.size(); ++n) {
    num += (signal[n] - reference[n]) * (signal[n] - reference[n]);
    den += reference[n] * reference[n];
  }
  return std::sqrt(num / den);
}

}  // namespace tipforce
