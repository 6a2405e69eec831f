#include "tipforce/detail/forward_setup.hpp"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <numbers>
#include <string>

#include "tipforce/assert.hpp"
#include "sampled_base.hpp"
#include "tipforce/drive.hpp"

namespace tipforce::detail {

void check_forward_batch(const ForwardProblem& pb, const ForwardBatch& batch, int max_modes) {
  TIPFORCE_THROW_UNLESS(pb.modal && pb.step && pb.window, "forward problem is incomplete");
  const Window& w = *pb.window;
  const int M = pb.modal->n_modes(), N = w.n_samples(), S = batch.n_sets;
  const int model = static_cast<int>(pb.model), drive = static_cast<int>(w.drive.kind);
  TIPFORCE_THROW_UNLESS(model >= static_cast<int>(ForceModelKind::none) && model <= static_cast<int>(ForceModelKind::dmt_viscous),
                        "unknown force model kind " + std::to_string(model));
  TIPFORCE_THROW_UNLESS(drive >= static_cast<int>(DriveKind::sine) && drive <= static_cast<int>(DriveKind::sampled),
                        "unknown drive kind " + std::to_string(drive));
  TIPFORCE_THROW_UNLESS(M >= 1 && M <= max_modes, "too many modes");
  TIPFORCE_THROW_UNLESS(N >= 1 && S >= 1, "empty batch or window");
  TIPFORCE_THROW_UNLESS(N <= kMaxWindowSamples, "window longer than " + std::to_string(kMaxWindowSamples) + " samples");
  TIPFORCE_THROW_UNLESS(std::isfinite(w.t0_s), "window t0_s is not finite");
  // 0 is the model's default and infinity turns a refinement off; NaN or a negative value is neither.
  TIPFORCE_THROW_UNLESS(pb.contact_rad_per_substep >= 0 && pb.crossing_rad_per_substep >= 0,
                        "contact_rad_per_substep and crossing_rad_per_substep must be >= 0 (0: default)");
  TIPFORCE_THROW_UNLESS(pb.substeps >= 1 && pb.substeps <= 64, "substeps must be in [1, 64]");
  TIPFORCE_THROW_UNLESS(pb.samples_per_step >= 0 && pb.samples_per_step <= 2, "samples_per_step must be 0, 1 or 2");
  TIPFORCE_THROW_UNLESS(pb.samples_per_step != 2 || two_samples_fit(pb, batch),
                        "samples_per_step 2 needs substeps 1, an even number of samples, the displacement sensor "
                        "and a sine or chirp drive shared by the batch");
  TIPFORCE_THROW_UNLESS(pb.step->n_modes == M &&
                            std::abs(pb.step->dt_s * pb.substeps - w.sample_period_s) <= 1e-12 * w.sample_period_s,
                        "step coefficients do not match the window's sample period / substeps");
  TIPFORCE_THROW_UNLESS(batch.params.size() == static_cast<std::size_t>(ParameterLayout(pb.model).n_full()) * S,
                        "parameter array has the wrong size");
  TIPFORCE_THROW_UNLESS(batch.initial.size() == 1 || batch.initial.size() == static_cast<std::size_t>(S),
                        "initial states: one shared or one per set");
  for (const ModalState& s : batch.initial) {
    TIPFORCE_THROW_UNLESS(static_cast<int>(s.q.size()) == M && static_cast<int>(s.v.size()) == M,
                          "initial state has the wrong number of modes");
    for (int i = 0; i < M; ++i)
      TIPFORCE_THROW_UNLESS(std::isfinite(s.q[static_cast<std::size_t>(i)]) && std::isfinite(s.v[static_cast<std::size_t>(i)]),
                            "initial state of mode " + std::to_string(i + 1) + " is not finite");
  }
  if (w.drive.kind == DriveKind::sampled) {
    TIPFORCE_THROW_UNLESS(static_cast<int>(w.drive.base_m.size()) == N && N >= 3,
                          "a sampled drive needs one base value per sample (and at least 3 samples)");
    for (double y : w.drive.base_m) TIPFORCE_THROW_UNLESS(std::isfinite(y), "a sampled drive's base is not finite");
  }
  // A set's parameters are not checked here: a set outside its model's domain (a NaN, a negative
  // stiffness) gives a meaningless answer for that set alone, and the inversion keeps its sets
  // inside the parameter space's bounds, which the configuration checks.
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

static_assert(kPoints == kHoldPoints, "the step and its coefficients hold the force at the same points");

template <int P>
StepConstants<P> make_step_constants(const ModalModel& modal, const StepCoefficients& st) {
  const int M = modal.n_modes();
  TIPFORCE_DEMAND(M <= P && st.n_modes == M);
  StepConstants<P> k{};
  const double h = st.dt_s;
  for (int i = 0; i < M; ++i) {
    const Mode& m = modal.modes()[static_cast<std::size_t>(i)];
    const double phi = m.phi_tip, c = phi / modal.modal_mass_kg(), g = -m.gamma;
    k.a00[i] = st.a00[i];
    k.a01[i] = st.a01[i];
    k.a10[i] = st.a10[i];
    k.a11[i] = st.a11[i];
    k.u00[i] = st.u00[i];
    k.u01[i] = st.u01[i];
    k.u10[i] = st.u10[i];
    k.u11[i] = st.u11[i];
    for (int n = 0; n < kInner; ++n) {
      const double* back = &st.back[n][4 * static_cast<std::size_t>(i)];
      k.bzq[n][i] = phi * back[0];
      k.bzv[n][i] = phi * back[1];
      k.bdq[n][i] = phi * back[2];
      k.bdv[n][i] = phi * back[3];
    }
    for (int p = 0; p < kPoints; ++p) {
      const double eq = st.end_q[p][i], ev = st.end_v[p][i];
      k.fq[p][i] = c * eq;
      k.fv[p][i] = c * ev;
      k.gq[p][i] = g * eq;
      k.gv[p][i] = g * ev;
      k.tip.z_end[p] += phi * c * eq;
      k.tip.zd_end[p] += phi * c * ev;
      for (int n = 0; n < kInner; ++n) {
        const double* back = &st.back[n][4 * static_cast<std::size_t>(i)];
        const double aq = st.at_q[n][p][i], av = st.at_v[n][p][i];
        k.tip.z_at[n][p] += phi * c * aq;
        k.tip.zd_at[n][p] += phi * c * av;
        // What the step's end, reached back, misses of the inner point: the hold's own share.
        k.gz_at[n][p] += phi * g * (aq - (back[0] * eq + back[1] * ev));
        k.gzd_at[n][p] += phi * g * (av - (back[2] * eq + back[3] * ev));
      }
    }
    k.phi[i] = phi;
    k.gain[i] = modal.sensor_gain(i);
    k.omega[i] = m.omega_rad_per_s;
    k.zeta[i] = m.zeta;
    k.gamma[i] = m.gamma;
    k.inv_omega[i] = 1.0 / m.omega_rad_per_s;
    // The look-ahead follows the tip's smooth part (base and mode 1) by a cubic over each step,
    // whose error for mode 1 is at most its amplitude times (omega h)^4 / 384; every other mode
    // counts with its whole amplitude.
    const double wh = m.omega_rad_per_s * h;
    k.reach[i] = std::abs(phi) * (i == 0 ? wh * wh * wh * wh / 384.0 : 1.0);
  }
  k.h_s = h;
  double accel = 0;
  for (int i = 0; i < M; ++i) accel += k.phi[i] * k.phi[i] / modal.modal_mass_kg();
  k.tip_accel_per_n = accel;
  // The Lagrange basis through the hold's points, and its moment matrix's inverse.
  Eigen::Matrix<double, kPoints, kPoints> moments;
  for (int q = 0; q < kPoints; ++q) {
    double poly[kPoints] = {1, 0, 0, 0, 0};
    int degree = 0;
    for (int m = 0; m < kPoints; ++m) {
      if (m == q) continue;
      const double scale = 1.0 / (hold_node(q) - hold_node(m));
      for (int p = degree + 1; p >= 0; --p) poly[p] = ((p > 0 ? poly[p - 1] : 0.0) - hold_node(m) * poly[p]) * scale;
      ++degree;
    }
    for (int p = 0; p < kPoints; ++p) k.basis[q][p] = poly[p];
    for (int m = 0; m < kPoints; ++m) {
      double v = 0;
      for (int p = 0; p < kPoints; ++p) v += poly[p] / (p + m + 1);
      moments(m, q) = v;
    }
  }
  const Eigen::Matrix<double, kPoints, kPoints> inv = moments.inverse();
  for (int q = 0; q < kPoints; ++q)
    for (int m = 0; m < kPoints; ++m) k.moment_inv[q][m] = inv(q, m);
  return k;
}

template <int P>
const StepConstants<P>* StepLevels<P>::get(const ModalModel& modal, const StepCoefficients& step, int samples_per_step,
                                           const ForEach& for_each) {
  const double h_s = step.dt_s * samples_per_step;
  key_.clear();
  append_modal_constants(modal, key_);
  for (std::size_t e = 0; e < entries_.size(); ++e) {
    const Entry& x = entries_[e];
    if (x.h_s == h_s && same_bits(x.modal, key_)) {
      if (e + 1 != entries_.size()) std::rotate(entries_.begin() + static_cast<std::ptrdiff_t>(e),
                                                entries_.begin() + static_cast<std::ptrdiff_t>(e) + 1, entries_.end());
      return entries_.back().levels.data();
    }
  }
  if (entries_.size() == kEntries) entries_.erase(entries_.begin());
  Entry x;
  // The levels first: where the heap puts them against the block's state moves a 1 MHz solve by
  // ~5 % (the key allocated before them: 91-93k against 96-98k solves/s, one thread, interleaved).
  x.levels.resize(kSubstepLevels);
  x.modal = key_;
  x.h_s = h_s;
  const auto level = [&](int j) {
    x.levels[static_cast<std::size_t>(j)] =
        make_step_constants<P>(modal, j == 0 && samples_per_step == 1 ? step : make_step_coefficients(modal, h_s / (1 << j)));
  };
  if (for_each)
    for_each(kSubstepLevels, level);
  else
    for (int j = 0; j < kSubstepLevels; ++j) level(j);
  entries_.push_back(std::move(x));
  return entries_.back().levels.data();
}

ContactResolution contact_resolution(const ModalModel& modal, const ForwardProblem& problem) {
  ContactResolution r;
  r.omega1_rad_per_s = modal.modes()[0].omega_rad_per_s;
  r.k_static_n_per_m = modal.static_stiffness_n_per_m();
  r.rad_per_substep = problem.contact_rad_per_substep > 0 ? problem.contact_rad_per_substep
                                                          : default_contact_rad_per_substep(problem.model);
  r.crossing_rad_per_substep = problem.crossing_rad_per_substep > 0
                                   ? problem.crossing_rad_per_substep
                                   : default_crossing_rad_per_substep(problem.model);
  return r;
}

bool two_samples_fit(const ForwardProblem& problem, const ForwardBatch& batch) {
  const Window& w = *problem.window;
  return problem.substeps == 1 && w.n_samples() % 2 == 0 && problem.modal->sensor() == Sensor::displacement &&
         w.drive.kind != DriveKind::sampled && !batch.drive_varies;
}

int samples_per_step(const ForwardProblem& problem, const ForwardBatch& batch) {
  if (problem.samples_per_step > 0) return problem.samples_per_step;
  const double f1_hz = problem.modal->modes()[0].omega_rad_per_s / (2 * std::numbers::pi);
  const bool fine = problem.window->sample_period_s * f1_hz <= 1.0 / kTwoSampleStepsPerPeriod;
  return fine && two_samples_fit(problem, batch) ? 2 : 1;
}

DriveFunction analytic_drive(const Window& w, const double dp[4]) {
  DriveFunction f;
  f.kind = static_cast<int>(w.drive.kind);
  for (int k = 0; k < 4; ++k) f.params[k] = dp[k];
  f.t0_s = w.t0_s;
  f.sample_period_s = w.sample_period_s;
  return f;
}

namespace {

// A sine drive: its phase at every coarse step and middle, and the free steady state.
template <int P>
void make_sine_drive(const StepConstants<P>& c0, const Window& w, const double dp[4], int n, double dt, SharedDrive& d) {
  const double a = dp[0], omega = 2 * std::numbers::pi * dp[1], phase = dp[2];
  d.qr.assign(P, 0.0);
  d.qi.assign(P, 0.0);
  double az = a, bz = 0, ag = 0, bg = 0;
  for (int i = 0; i < P; ++i) {
    // Mode i's steady state: q = Im(Q e^{i theta}), Q = gamma a w^2 / (omega_i^2 - w^2 + 2 i zeta omega_i w).
    const double re = c0.omega[i] * c0.omega[i] - omega * omega, im = 2.0 * c0.zeta[i] * c0.omega[i] * omega;
    const double den = re * re + im * im;
    const double g = den > 0 ? c0.gamma[i] * a * omega * omega / den : 0.0;
    d.qr[i] = g * re;
    d.qi[i] = -g * im;
    az += c0.phi[i] * d.qr[i];
    bz += c0.phi[i] * d.qi[i];
    ag += c0.gain[i] * d.qr[i];
    bg += c0.gain[i] * d.qi[i];
  }
  const std::size_t un = static_cast<std::size_t>(n);
  for (auto* v : {&d.ph_s, &d.ph_c, &d.y, &d.zb, &d.zbd}) v->resize(un + 1);
  for (auto* v : {&d.zbn, &d.zbdn}) v->resize(un * kInner);
  // The phase at the steps and their inner points by rotation from an exact anchor every
  // kAnchorSteps steps: four sin/cos per step took ~10 % of a warm 1 MHz window's serial time
  // (the drive is remade per window: its t0 moves). Rounding grows by ~1e-16 per rotation.
  constexpr int kAnchorSteps = 16;
  SharedSineView& v = d.sine;
  for (int k = 0; k < kSubstepLevels; ++k) {
    const double hl = dt / (1 << k);
    for (int p = 0; p + 1 < kPoints; ++p) {
      v.rot[k].c[p] = std::cos(omega * hold_node(p + 1) * hl);
      v.rot[k].s[p] = std::sin(omega * hold_node(p + 1) * hl);
    }
  }
  // Rotation by omega dt times the node after the start: rc[n], rs[n] for node n + 1 (the last: one step).
  const double* rc = v.rot[0].c;
  const double* rs = v.rot[0].s;
  auto put = [&](int j, int p, double s, double c) {
    const double zb = az * s + bz * c, zbd = omega * (az * c - bz * s);
    if (p == 0) {
      d.ph_s[j] = s;
      d.ph_c[j] = c;
      d.y[j] = a * s;
      d.zb[j] = zb;
      d.zbd[j] = zbd;
    } else {
      d.zbn[static_cast<std::size_t>(j) * kInner + p - 1] = zb;
      d.zbdn[static_cast<std::size_t>(j) * kInner + p - 1] = zbd;
      if (p == 2 && !d.ym.empty()) d.ym[j] = a * s;  // the midpoint (node 1/2)
    }
  };
  double s = 0, c = 1;
  for (int j = 0; j <= n; ++j) {
    if (j % kAnchorSteps == 0) {
      const double th = omega * (w.t0_s + j * dt) + phase;
      s = std::sin(th);
      c = std::cos(th);
    }
    put(j, 0, s, c);
    if (j == n) break;
    for (int p = 1; p + 1 < kPoints; ++p) put(j, p, s * rc[p - 1] + c * rs[p - 1], c * rc[p - 1] - s * rs[p - 1]);
    const double sn = s * rc[kPoints - 2] + c * rs[kPoints - 2];
    c = c * rc[kPoints - 2] - s * rs[kPoints - 2];
    s = sn;
  }
  v.az = az;
  v.bz = bz;
  v.ag = ag;
  v.bg = bg;
  v.omega = omega;
}

// A held drive (chirp or sampled base): base, middles and increments per coarse step.
template <int P>
void make_held_drive(const StepConstants<P>& c0, const Window& w, int n, double dt, SharedDrive& d) {
  const DriveFunction& fn = d.hold.fn;
  const std::size_t un = static_cast<std::size_t>(n);
  d.y.resize(un + 1);
  d.yd.resize(un + 1);
  d.zbn.resize(un * kInner);
  d.zbdn.resize(un * kInner);
  d.dq.resize(un * P);
  d.dv.resize(un * P);
  StepInput<P, 1> in;
  for (int j = 0; j <= n; ++j) {
    const Motion m = fn.at(w.t0_s + j * dt);
    d.y[j] = m.y;
    d.yd[j] = m.yd;
    if (j == n) break;
    held_drive_step(c0, fn, w.t0_s + j * dt, 0, in);
    for (int p = 0; p < kInner; ++p) {
      d.zbn[static_cast<std::size_t>(j) * kInner + p] = in.zbn[p][0];
      d.zbdn[static_cast<std::size_t>(j) * kInner + p] = in.zbdn[p][0];
    }
    for (int i = 0; i < P; ++i) {
      d.dq[static_cast<std::size_t>(j) * P + i] = in.dq[i][0];
      d.dv[static_cast<std::size_t>(j) * P + i] = in.dv[i][0];
    }
  }
}

const double* own_storage(const std::vector<double>& a) { return a.empty() ? nullptr : a.data(); }

}  // namespace

template <int P>
void make_shared_drive(const StepConstants<P>& c0, const Window& w, const double dp[4],
                       int substeps, int samples_per_step, SharedDrive& d) {
  const int ns = w.n_samples();
  TIPFORCE_DEMAND(samples_per_step == 1 || (substeps == 1 && ns % samples_per_step == 0));
  const int n = ns * substeps / samples_per_step;  // coarse steps
  const double dt = w.sample_period_s * samples_per_step / substeps;
  TIPFORCE_DEMAND(std::abs(c0.h_s - dt) <= 1e-12 * dt);
  d = SharedDrive{};
  d.padded = P;
  d.held = w.drive.kind != DriveKind::sine;
  if (samples_per_step == 2) d.ym.assign(static_cast<std::size_t>(n), 0.0);
  if (!d.held) {
    make_sine_drive(c0, w, dp, n, dt, d);
    point_views(d, own_storage, d.sine, d.hold);
    return;
  }
  d.hold.fn = analytic_drive(w, dp);
  if (w.drive.kind == DriveKind::sampled) {
    TIPFORCE_DEMAND(static_cast<int>(w.drive.base_m.size()) == ns && ns >= 3);
    SampledBase base = make_sampled_base(w.drive.base_m, w.sample_period_s);
    d.ys = std::move(base.y_m);
    d.vs = std::move(base.yd_m_per_s);
    d.as = std::move(base.ydd_m_per_s2);
    d.hold.fn.n_samples = ns;
  }
  // make_held_drive evaluates the drive function through its views.
  point_views(d, own_storage, d.sine, d.hold);
  make_held_drive(c0, w, n, dt, d);
  for (std::size_t j = 0; j < d.ym.size(); ++j) d.ym[j] = d.hold.fn.at(w.t0_s + (static_cast<double>(j) + 0.5) * dt).y;
  point_views(d, own_storage, d.sine, d.hold);
}

#define TIPFORCE_INSTANTIATE(P)                                                                                   \
  template StepConstants<P> make_step_constants<P>(const ModalModel&, const StepCoefficients&);                  \
  template class StepLevels<P>;                                                                                   \
  template void make_shared_drive<P>(const StepConstants<P>&, const Window&, const double[4], int, int,     \
                                     SharedDrive&);
TIPFORCE_INSTANTIATE(1)
TIPFORCE_INSTANTIATE(2)
TIPFORCE_INSTANTIATE(4)
TIPFORCE_INSTANTIATE(8)
TIPFORCE_INSTANTIATE(16)
TIPFORCE_INSTANTIATE(32)
#undef TIPFORCE_INSTANTIATE

void SharedDriveKey::assign(const ModalModel& modal, const StepCoefficients& step, const Window& w,
                            const double drive_params[4], int substeps, int samples_per_step, int padded) {
  values_.clear();
  for (double x : {static_cast<double>(w.drive.kind), w.t0_s, w.sample_period_s, static_cast<double>(w.n_samples()),
                   static_cast<double>(substeps), static_cast<double>(samples_per_step), static_cast<double>(padded),
                   step.dt_s})
    values_.push_back(x);
  if (w.drive.kind == DriveKind::sampled)
    values_.insert(values_.end(), w.drive.base_m.begin(), w.drive.base_m.end());
  else
    values_.insert(values_.end(), drive_params, drive_params + 4);
  append_modal_constants(modal, values_);
}

bool SharedDriveKey::operator==(const SharedDriveKey& other) const { return same_bits(values_, other.values_); }

void append_modal_constants(const ModalModel& modal, std::vector<double>& out) {
  for (double x : {static_cast<double>(modal.n_modes()), static_cast<double>(modal.sensor() == Sensor::displacement),
                   modal.modal_mass_kg()})
    out.push_back(x);
  for (int i = 0; i < modal.n_modes(); ++i) {
    const Mode& m = modal.modes()[static_cast<std::size_t>(i)];
    for (double x : {m.omega_rad_per_s, m.zeta, m.gamma, m.phi_tip, modal.sensor_gain(i)}) out.push_back(x);
  }
}

bool same_bits(const std::vector<double>& a, const std::vector<double>& b) {
  return a.size() == b.size() && (a.empty() || std::memcmp(a.data(), b.data(), a.size() * sizeof(double)) == 0);
}

}  // namespace tipforce::detail
