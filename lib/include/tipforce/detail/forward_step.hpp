#pragma once
// The forward solver's per-step arithmetic for a block of L parameter sets, written once for both
// backends: the CPU runs it with L = 4, 8 or 16 lanes (the lane loops vectorise across sets), the
// CUDA kernel with L = 1 (one thread per set). See lib/src/DESIGN.md for the scheme and its error.
//
// One sample period is one exact step in free flight. Where a lane is in contact, or its predicted
// path over the period reaches the surface, the whole block advances the period in K substeps, K a
// power of two sized from the stiffest lane's contact frequency (contact_substeps): the linear
// force hold's error is second order in the step, and only contact needs the short step.
#include <cmath>

#include "tipforce/detail/contact_step.hpp"

// The lane loops carry no dependence between lanes; GCC's vectoriser is told so (nvcc and clang
// have no use for the hint).
#if defined(__GNUC__) && !defined(__clang__) && !defined(__CUDACC__)
#define TIPFORCE_IVDEP _Pragma("GCC ivdep")
#else
#define TIPFORCE_IVDEP
#endif

namespace tipforce::detail {

inline constexpr int kMaxModes = 32;
// Substep levels: level j advances a sample period in 2^j steps.
inline constexpr int kSubstepLevels = 11;  // up to 1024 substeps
inline constexpr int kMaxSubsteps = 1 << (kSubstepLevels - 1);

// Per-mode constants of one step length h, indexed by mode; entries past the model's modes are zero
// (so padded modes stay at exactly zero). Plain arrays so that a kernel can take them by value.
template <int P>
struct StepConstants {
  double a00[P], a01[P], a10[P], a11[P];       // transition matrix over h
  double cs_q[P], cs_v[P], ce_q[P], ce_v[P];   // (phi / mu L) * responses to the force hold's start / end
  double phi[P], gain[P], gamma[P];            // tip shape, sensor gain, base coupling
  double curv_q[P], curv_v[P];                 // |phi| (1 + 2 zeta) (omega^2, omega): free_curvature_bound
  double wq0[P], wv0[P], wqm[P], wvm[P], wq1[P], wv1[P];  // quadratic hold of the base acceleration
  TipStepResponse tip;                          // the tip's response to the force holds
  double h_s;                                   // the step
};

// What sizes the contact substeps: mode 1's frequency and the static stiffness give the tip's
// effective mass; `rad_per_substep` is the phase of the contact oscillation one substep may span.
struct ContactResolution {
  double omega1_rad_per_s = 0;
  double k_static_n_per_m = 0;
  double rad_per_substep = 0.01;  // ForwardProblem::contact_rad_per_substep
  // Contact steps are run at their level and the next finer one and combined (Richardson): the
  // scheme is symmetric, so its error has only even powers of the substep and the combination
  // cancels the second-order term (ForwardProblem::extrapolate_contact).
  bool extrapolate = false;
};

// The base motion of the analytic drives (SPEC section 1), on host and device.
struct Motion {
  double y, yd, ydd;
};
TIPFORCE_HD Motion analytic_base_motion(int kind, double a, double f, double phase, double g, double t) {
  constexpr double two_pi = 2.0 * 3.14159265358979323846;
  double th, thd, thdd;
  if (kind == 1 /* DriveKind::chirp: y = a sin(2 pi (f + g t) t + phase) */) {
    th = two_pi * (f + g * t) * t + phase;
    thd = two_pi * (f + 2.0 * g * t);
    thdd = 2.0 * two_pi * g;
  } else {
    th = two_pi * f * t + phase;
    thd = two_pi * f;
    thdd = 0.0;
  }
  const double s = sin(th), c = cos(th);
  return {a * s, a * c * thd, a * (c * thdd - s * thd * thd)};
}

// A drive as a function of time: analytic (sine, chirp) or a sampled base signal, whose position,
// velocity and acceleration at the samples (finite differences, one extrapolated sample past the
// end) are linearly interpolated.
struct DriveFunction {
  int kind = 0;  // DriveKind value
  double params[4] = {0, 0, 0, 0};
  double t0_s = 0, sample_period_s = 1;
  int n_samples = 0;                       // sampled: length of ys/vs/as minus one
  const double* ys = nullptr;              // sampled: n_samples + 1 values each
  const double* vs = nullptr;
  const double* as = nullptr;

  TIPFORCE_HD Motion at(double t) const {
    if (kind != 2) return analytic_base_motion(kind, params[0], params[1], params[2], params[3], t);
    double x = (t - t0_s) / sample_period_s;
    x = x < 0 ? 0 : (x > n_samples ? n_samples : x);
    int k = static_cast<int>(x);
    k = k > n_samples - 1 ? n_samples - 1 : k;
    const double u = x - k;
    return {ys[k] + u * (ys[k + 1] - ys[k]), vs[k] + u * (vs[k + 1] - vs[k]), as[k] + u * (as[k + 1] - as[k])};
  }
};

// The drive's contribution to every mode over one step (quadratic hold of -gamma * yddot through
// the step's start, middle and end), and the base at the step end. LD = 1: shared by all lanes.
template <int P, int LD>
struct StepDrive {
  double dq[P][LD], dv[P][LD];
  double y1[LD], yd1[LD];
};

template <int P, int LD>
TIPFORCE_HD void drive_increment(const StepConstants<P>& c, int M, double acc0, double accm, double acc1, int lane,
                                 StepDrive<P, LD>& d) {
  for (int i = 0; i < M; ++i) {
    d.dq[i][lane] = -c.gamma[i] * (c.wq0[i] * acc0 + c.wqm[i] * accm + c.wq1[i] * acc1);
    d.dv[i][lane] = -c.gamma[i] * (c.wv0[i] * acc0 + c.wvm[i] * accm + c.wv1[i] * acc1);
  }
}

// Increments of the step [t, t + h] of a drive function, for one lane slot.
template <int P, int LD>
TIPFORCE_HD void drive_step(const StepConstants<P>& c, int M, const DriveFunction& f, double t, int lane,
                            StepDrive<P, LD>& d) {
  const double h = c.h_s;
  const Motion m1 = f.at(t + h);
  drive_increment(c, M, f.at(t).ydd, f.at(t + 0.5 * h).ydd, m1.ydd, lane, d);
  d.y1[lane] = m1.y;
  d.yd1[lane] = m1.yd;
}

// The state of L parameter sets.
template <int P, int L>
struct LaneBlock {
  double q[P][L], v[P][L];
  double f[L], z[L], zd[L];  // force, tip position and velocity at the current instant
  double zdd[L];             // tip acceleration, estimated from the last step (for the contact look-ahead)
  double zdd_bound[L];       // a bound on the free tip's acceleration over the step (0 where not needed)
  double y[L];               // base position
  double zone[L];            // how far below the surface (m) the tip may come before contact needs substeps
  int linear_level[L];       // spring and Kelvin-Voigt: the substep level of any step near contact
  bool in[L];                // contact branch
};

// Spring and Kelvin-Voigt steps that stay on their branch, for all lanes at once without branches
// (vectorised on the CPU); lanes whose branch changes are flagged for the exact scalar step.
template <int kModel, int L>
TIPFORCE_HD void regular_linear_contact(const LaneForce* lf, const TipStepResponse& tip, const double* zh,
                                        const double* zdh, const bool* in, double* f, double* z, double* zd,
                                        double* al, double* be, bool* cross) {
TIPFORCE_IVDEP
  for (int l = 0; l < L; ++l) {
    const double k = lf[l].k, h = lf[l].h, c = kModel == kKelvinVoigt ? lf[l].c : 0.0;
    double fin = (-k * (zh[l] - h) - c * zdh[l]) / (1.0 + k * tip.z_end + c * tip.v_end);
    if (kModel == kKelvinVoigt) fin = fin < 0.0 ? fin : 0.0;
    const double f1 = in[l] ? fin : 0.0;
    const double z1 = zh[l] + tip.z_end * f1, zd1 = zdh[l] + tip.v_end * f1;
    const double delta = z1 - h;
    const double s1 = kModel == kKelvinVoigt ? fmin(k * delta, k * delta + c * zd1) : delta;
    cross[l] = (s1 > 0) != in[l];
    f[l] = f1;
    z[l] = z1;
    zd[l] = zd1;
    al[l] = f1;
    be[l] = 0.0;
  }
}

// One step of length c.h_s for every lane: the exact linear update with the force held at its
// step-start value, then the step-end force solved implicitly and the hold's correction.
template <int P, int L, int LD>
TIPFORCE_HD void advance_step(const StepConstants<P>& c, int M, int model, const LaneForce* lf,
                              const StepDrive<P, LD>& d, LaneBlock<P, L>& b) {
  double zh[L], zdh[L];
  for (int l = 0; l < L; ++l) {
    b.y[l] = zh[l] = d.y1[LD == 1 ? 0 : l];
    zdh[l] = d.yd1[LD == 1 ? 0 : l];
  }
  for (int i = 0; i < M; ++i) {
    const double a00 = c.a00[i], a01 = c.a01[i], a10 = c.a10[i], a11 = c.a11[i];
    const double csq = c.cs_q[i], csv = c.cs_v[i], ph = c.phi[i];
TIPFORCE_IVDEP
    for (int l = 0; l < L; ++l) {
      const double qn = a00 * b.q[i][l] + a01 * b.v[i][l] + csq * b.f[l] + d.dq[i][LD == 1 ? 0 : l];
      const double vn = a10 * b.q[i][l] + a11 * b.v[i][l] + csv * b.f[l] + d.dv[i][LD == 1 ? 0 : l];
      b.q[i][l] = qn;
      b.v[i][l] = vn;
      zh[l] += ph * qn;
      zdh[l] += ph * vn;
    }
  }
  if (model == kNone) {
    for (int l = 0; l < L; ++l) {
      b.z[l] = zh[l];
      b.zd[l] = zdh[l];
    }
    return;
  }
  double al[L], be[L];
  auto exact = [&](int l, double zn, double zdn, double fn, bool inn) {
    const ContactResult r = contact_step(lf[l], c.tip, zh[l], zdh[l], zn, zdn, fn, inn);
    b.f[l] = r.f;
    b.in[l] = r.in;
    al[l] = r.alpha;
    be[l] = r.beta;
    b.z[l] = zh[l] + c.tip.z_end * r.alpha + c.tip.z_start * r.beta;
    b.zd[l] = zdh[l] + c.tip.v_end * r.alpha + c.tip.v_start * r.beta;
  };
  if (model == kSpring || model == kKelvinVoigt) {
    double z0[L], zd0[L], f0[L];
    bool in0[L], cross[L];
    for (int l = 0; l < L; ++l) {
      z0[l] = b.z[l];
      zd0[l] = b.zd[l];
      f0[l] = b.f[l];
      in0[l] = b.in[l];
    }
    if (model == kSpring)
      regular_linear_contact<kSpring, L>(lf, c.tip, zh, zdh, b.in, b.f, b.z, b.zd, al, be, cross);
    else
      regular_linear_contact<kKelvinVoigt, L>(lf, c.tip, zh, zdh, b.in, b.f, b.z, b.zd, al, be, cross);
    for (int l = 0; l < L; ++l)
      if (cross[l]) exact(l, z0[l], zd0[l], f0[l], in0[l]);
  } else {
    for (int l = 0; l < L; ++l) exact(l, b.z[l], b.zd[l], b.f[l], b.in[l]);
  }
  // In free flight every hold is zero: most steps need no correction at all.
  bool any = false;
  for (int l = 0; l < L; ++l) any |= (al[l] != 0.0) | (be[l] != 0.0);
  if (!any) return;
  for (int i = 0; i < M; ++i) {
    const double ceq = c.ce_q[i], cev = c.ce_v[i], csq = c.cs_q[i], csv = c.cs_v[i];
TIPFORCE_IVDEP
    for (int l = 0; l < L; ++l) {
      b.q[i][l] += ceq * al[l] + csq * be[l];
      b.v[i][l] += cev * al[l] + csv * be[l];
    }
  }
}

// The stiffness and the damping coefficient the contact adds at penetration pen (m), for sizing
// substeps.
TIPFORCE_HD void contact_stiffness(const LaneForce& p, double pen, double& k_n_per_m, double& c_ns_per_m) {
  pen = pen > 0 ? pen : 0;
  switch (p.model) {
    case kSpring: k_n_per_m = p.k; c_ns_per_m = 0; return;
    case kKelvinVoigt: k_n_per_m = p.k; c_ns_per_m = p.c; return;
    case kHertz:
    case kDmt: k_n_per_m = 1.5 * p.big_k * sqrt(pen); c_ns_per_m = 0; return;
    case kDmtViscous: k_n_per_m = 1.5 * p.big_k * sqrt(pen); c_ns_per_m = p.eta_sqrt_r * sqrt(pen); return;
    default: k_n_per_m = 0; c_ns_per_m = 0;
  }
}

// Below this fraction of the static stiffness a DMT attraction's stiffness needs no substeps.
// Measured: at 0.02 the free-flight steps just outside this zone left a 1e-4 error in the
// bistable DMT transients (from steady tapping at 1 MHz); at 0.0005 (a gap of ~8 nm for the
// paper's tip) the error is 1e-5.
inline constexpr double kAttractionRefineFraction = 0.0005;
// Weight of the transit rate |zd| / gap against the contact frequency in sizing substeps.
inline constexpr double kTransitWeight = 0.1;

// How far below the surface the tip may come before lane_level can ask for substeps: 0 for the
// repulsive laws; for DMT the gap where the attraction's stiffness reaches its refinement threshold.
TIPFORCE_HD double refine_zone(const LaneForce& lf, const ContactResolution& res) {
  if (lf.model != kDmt && lf.model != kDmtViscous) return 0.0;
  const double g = cbrt(2.0 * lf.hr6 / (kAttractionRefineFraction * res.k_static_n_per_m));
  return g > lf.a0 ? g : lf.a0;
}

// The level whose substep spans at most res.rad_per_substep of the fastest of: the contact
// frequency with stiffness k added, the damping rate of c, and a transit rate (1/s).
TIPFORCE_HD int level_for(double k_n_per_m, double c_ns_per_m, double transit, double dt_s, const ContactResolution& res) {
  const double m_eff = res.k_static_n_per_m / (res.omega1_rad_per_s * res.omega1_rad_per_s);
  const double rate =
      fmax(fmax(res.omega1_rad_per_s * sqrt(1.0 + k_n_per_m / res.k_static_n_per_m), c_ns_per_m / m_eff), transit);
  const double want = rate * dt_s / res.rad_per_substep;
  int level = 0;
  while (level < kSubstepLevels - 1 && (1 << level) < want) ++level;
  return level;
}

// Substep level (log2 of the substeps) of lane l for the coming step of length dt_s: -1 (free
// flight: one exact step) where the lane is out of contact and its predicted path (a parabola through the tip's position, velocity
// and acceleration, with a margin) stays off the surface, else sized from its contact frequency.
// Each lane's level depends on its own state only, so a set's result does not depend on the sets
// it is solved beside.
template <int P, int L>
TIPFORCE_HD int lane_level(const LaneBlock<P, L>& b, int l, const LaneForce& lf, int model, double dt_s,
                           const ContactResolution& res) {
  if (model == kNone) return -1;
  const double z = b.z[l], zd = b.zd[l], a = fmax(b.zdd[l], b.zdd_bound[l]);
  // The highest point of z + zd s + a s^2 / 2 over s in [0, dt].
  double s_top = a < 0 ? -zd / a : dt_s;
  s_top = s_top < 0 ? 0 : (s_top > dt_s ? dt_s : s_top);
  const double z_top = fmax(z + zd * dt_s + 0.5 * a * dt_s * dt_s, z + zd * s_top + 0.5 * a * s_top * s_top);
  const double margin = 0.25 * (fabs(zd) * dt_s + 0.5 * fabs(a) * dt_s * dt_s);
  const bool dmt = model == kDmt || model == kDmtViscous;
  const double pen = fmax(z_top, z) - lf.h + (dmt ? lf.a0 : 0.0);
  double k = 0, c = 0, transit = 0;
  if (b.in[l] || pen + margin > 0) {
    contact_stiffness(lf, pen + margin, k, c);
    // The viscous DMT damper grows as sqrt(penetration): it changes on the scale of the
    // penetration itself, which the tip crosses at |zd| / penetration.
    if (model == kDmtViscous) transit = kTransitWeight * (fabs(zd) + fabs(a) * dt_s) / fmax(pen + margin, 1e-3 * lf.a0);
  } else if (dmt) {
    // Out of contact the DMT attraction H R / (6 d^2) varies on the length scale of the gap d
    // itself: the tip crosses it at the rate |zd| / d, far faster than any oscillation, and its
    // stiffness H R / (3 d^3) at the nearest predicted gap says whether that matters.
    const double gap = fmax(lf.a0 - pen - margin, lf.a0);
    k = 2.0 * lf.hr6 / (gap * gap * gap);
    if (k < kAttractionRefineFraction * res.k_static_n_per_m) return -1;
    transit = kTransitWeight * (fabs(zd) + fabs(a) * dt_s) / gap;
  } else {
    return -1;
  }
  return level_for(k, c, transit, dt_s, res);
}

}  // namespace tipforce::detail

namespace tipforce::detail {

// The drive of every lane shared (LD = 1): coarse steps read the window's precomputed increments
// (the same for all sets), substeps evaluate the drive function.
struct SharedDriveSource {
  const double* y_m = nullptr;   // [j], j <= coarse steps
  const double* yd_m = nullptr;
  const double* dq = nullptr;    // [j * dq_stride + i]
  const double* dv = nullptr;
  int dq_stride = 0;
  DriveFunction fn;

  template <int P, int L>
  TIPFORCE_HD void coarse(const StepConstants<P>&, int M, int j, double, StepDrive<P, 1>& d) const {
    for (int i = 0; i < M; ++i) {
      d.dq[i][0] = dq[static_cast<long>(j) * dq_stride + i];
      d.dv[i][0] = dv[static_cast<long>(j) * dq_stride + i];
    }
    d.y1[0] = y_m[j + 1];
    d.yd1[0] = yd_m[j + 1];
  }
  template <int P, int L>
  TIPFORCE_HD void fine(const StepConstants<P>& c, int M, double t, StepDrive<P, 1>& d) const {
    drive_step(c, M, fn, t, 0, d);
  }
};

// A drive per lane (drive parameters among the unknowns): every step evaluates each lane's drive.
template <int L>
struct PerLaneDriveSource {
  DriveFunction fn[L];

  template <int P, int L2>
  TIPFORCE_HD void coarse(const StepConstants<P>& c, int M, int, double t, StepDrive<P, L>& d) const {
    for (int l = 0; l < L; ++l) drive_step(c, M, fn[l], t, l, d);
  }
  template <int P, int L2>
  TIPFORCE_HD void fine(const StepConstants<P>& c, int M, double t, StepDrive<P, L>& d) const {
    for (int l = 0; l < L; ++l) drive_step(c, M, fn[l], t, l, d);
  }
};

// Advances every lane over coarse step j (from t_s, length levels[0].h_s) at one substep level.
template <int P, int L, int LD, class Source>
TIPFORCE_HD void advance_at_level(const StepConstants<P>* levels, int level, int M, int model, const LaneForce* lf,
                                  const Source& src, int j, double t_s, LaneBlock<P, L>& b) {
  StepDrive<P, LD> d;
  if (level == 0) {
    src.template coarse<P, L>(levels[0], M, j, t_s, d);
    advance_step(levels[0], M, model, lf, d, b);
    return;
  }
  const StepConstants<P>& c = levels[level];
  const int n = 1 << level;
  for (int s = 0; s < n; ++s) {
    src.template fine<P, L>(c, M, t_s + s * c.h_s, d);
    advance_step(c, M, model, lf, d, b);
  }
}

template <int P, int L>
TIPFORCE_HD void copy_lane(int M, const LaneBlock<P, L>& from, int l, LaneBlock<P, L>& to) {
  for (int i = 0; i < M; ++i) {
    to.q[i][l] = from.q[i][l];
    to.v[i][l] = from.v[i][l];
  }
  to.f[l] = from.f[l];
  to.z[l] = from.z[l];
  to.zd[l] = from.zd[l];
  to.zdd[l] = from.zdd[l];
  to.zdd_bound[l] = from.zdd_bound[l];
  to.y[l] = from.y[l];
  to.zone[l] = from.zone[l];
  to.linear_level[l] = from.linear_level[l];
  to.in[l] = from.in[l];
}

// The block's first M modes and its per-lane values.
template <int P, int L>
TIPFORCE_HD void copy_block(int M, const LaneBlock<P, L>& from, LaneBlock<P, L>& to) {
  for (int l = 0; l < L; ++l) copy_lane(M, from, l, to);
}

// Above this phase of mode 1 per sample the look-ahead's acceleration, estimated from the last
// step, lags too far behind the tip: a short grazing contact inside one step of 2e-6 s went unseen
// (4e-4 error). There the look-ahead also uses a bound on the free tip's acceleration.
inline constexpr double kCurvatureBoundPhase = 0.1;

// Out of contact each mode oscillates with amplitude at most |q| + |v| / omega, so its acceleration
// over the step is at most (1 + 2 zeta) (omega^2 |q| + omega |v|); the drive's direct part, 1/Q of
// the response, is covered by the 10 % margin.
template <int P, int L>
TIPFORCE_HD void free_curvature_bound(const StepConstants<P>& c, int M, LaneBlock<P, L>& b) {
  for (int l = 0; l < L; ++l) b.zdd_bound[l] = 0.0;
  for (int i = 0; i < M; ++i) {
    const double cq = c.curv_q[i], cv = c.curv_v[i];
TIPFORCE_IVDEP
    for (int l = 0; l < L; ++l) b.zdd_bound[l] += cq * fabs(b.q[i][l]) + cv * fabs(b.v[i][l]);
  }
  for (int l = 0; l < L; ++l) b.zdd_bound[l] *= 1.1;
}

// Where each lane's step comes from: the run at level `fine` (0 in free flight), and for an
// extrapolated contact step also the run at `coarse` = fine - 1 (-1: none).
struct LanePlan {
  int fine, coarse;
};

template <int L>
TIPFORCE_HD LanePlan plan_lane(int level, const ContactResolution& res) {
  if (level < 0) return {0, -1};
  if (!res.extrapolate) return {level, -1};
  const int fine = level + 1 < kSubstepLevels ? level + 1 : kSubstepLevels - 1;
  return {fine, fine - 1};
}

// The Richardson combination of a lane's fine and coarse results; the contact branch and force
// are re-derived from the combined tip state so that the next step starts consistent.
template <int P, int L>
TIPFORCE_HD void extrapolate_lane(int M, const LaneForce& lf, const LaneBlock<P, L>& coarse, int l, LaneBlock<P, L>& b) {
  constexpr double w = 1.0 / 3.0;  // (4 fine - coarse) / 3: the substep halves, the error quarters
  for (int i = 0; i < M; ++i) {
    b.q[i][l] += w * (b.q[i][l] - coarse.q[i][l]);
    b.v[i][l] += w * (b.v[i][l] - coarse.v[i][l]);
  }
  b.z[l] += w * (b.z[l] - coarse.z[l]);
  b.zd[l] += w * (b.zd[l] - coarse.zd[l]);
  b.in[l] = switching(lf, b.z[l], b.zd[l]) > 0;
  b.f[l] = branch_force(lf, b.in[l], b.z[l], b.zd[l]);
}

// Out of contact spring, Kelvin-Voigt and Hertz exert no force, so a step the look-ahead clears for
// every lane is the free step, without the contact arithmetic. If a lane nevertheless ends inside
// the sample (the look-ahead is a prediction), the block is put back and false returned.
template <int P, int L, int LD, class Source>
TIPFORCE_HD bool free_step_without_force(const StepConstants<P>& c, int M, int model, const LaneForce* lf,
                                         const Source& src, int j, double t_s, LaneBlock<P, L>& b) {
  if (model != kNone && model != kSpring && model != kKelvinVoigt && model != kHertz) return false;
  StepDrive<P, LD> d;
  src.template coarse<P, L>(c, M, j, t_s, d);
  if (model == kNone) {
    advance_step(c, M, kNone, lf, d, b);
    return true;
  }
  double q0[P][L], v0[P][L], y0[L], z0[L], zd0[L];
  for (int i = 0; i < M; ++i)
    for (int l = 0; l < L; ++l) {
      q0[i][l] = b.q[i][l];
      v0[i][l] = b.v[i][l];
    }
  for (int l = 0; l < L; ++l) {
    y0[l] = b.y[l];
    z0[l] = b.z[l];
    zd0[l] = b.zd[l];
  }
  advance_step(c, M, kNone, lf, d, b);
  // Every law's switching function is positive only inside the sample (z > h).
  int crossed = 0;
  for (int l = 0; l < L; ++l) crossed |= static_cast<int>(b.z[l] > lf[l].h);
  if (!crossed) return true;
  for (int i = 0; i < M; ++i)
    for (int l = 0; l < L; ++l) {
      b.q[i][l] = q0[i][l];
      b.v[i][l] = v0[i][l];
    }
  for (int l = 0; l < L; ++l) {
    b.y[l] = y0[l];
    b.z[l] = z0[l];
    b.zd[l] = zd0[l];
  }
  return false;
}

// Advances coarse step j for every lane, each at its own substep level: the block runs once per
// distinct level needed (all lanes, so that the lane loops stay whole vectors) and keeps each
// lane's result from the run at its level.
template <int P, int L, int LD, class Source>
TIPFORCE_HD void advance_coarse_step(const StepConstants<P>* levels, int M, int model, const LaneForce* lf,
                                     const ContactResolution& res, const Source& src, int j, double t_s,
                                     LaneBlock<P, L>& b) {
  const double h = levels[0].h_s;
  const double inv_h = 1.0 / h;
  double zd0[L];
  for (int l = 0; l < L; ++l) zd0[l] = b.zd[l];
  // A bound first, for all lanes at once: the highest the tip can get within the step (with the
  // margin lane_level uses). Most steps are far from the surface, and take the free step at once.
  // (Plain compares rather than fmax, which is a library call, and int flags rather than bool, so
  // that this loop vectorises: it runs every sample.)
  int near[L];
  if (model != kNone && res.omega1_rad_per_s * h > kCurvatureBoundPhase) free_curvature_bound(levels[0], M, b);
TIPFORCE_IVDEP
  for (int l = 0; l < L; ++l) {
    const double acc_est = 1.25 * fabs(b.zdd[l]), acc = acc_est > b.zdd_bound[l] ? acc_est : b.zdd_bound[l];
    const double reach = 1.25 * fabs(b.zd[l]) * h + 0.5 * acc * h * h;
    near[l] = static_cast<int>(b.in[l]) | static_cast<int>(b.z[l] + reach - lf[l].h + b.zone[l] > 0);
  }
  int any_near = 0;
  for (int l = 0; l < L; ++l) any_near |= near[l];
  if (model == kNone || !any_near) {
    // Every lane free: the free step, or (DMT's attraction; a lane that reached the sample after
    // all) the model's step at level 0, which is what such a lane gets beside near lanes too.
    if (!free_step_without_force<P, L, LD>(levels[0], M, model, lf, src, j, t_s, b))
      advance_at_level<P, L, LD>(levels, 0, M, model, lf, src, j, t_s, b);
    for (int l = 0; l < L; ++l) b.zdd[l] = (b.zd[l] - zd0[l]) * inv_h;
    return;
  }
  int lev[L];
  if (model == kSpring || model == kKelvinVoigt) {
    // The linear laws' contact frequency does not depend on the state: a lane near the surface
    // takes its fixed level.
    for (int l = 0; l < L; ++l) lev[l] = near[l] ? b.linear_level[l] : -1;
  } else {
    for (int l = 0; l < L; ++l) lev[l] = near[l] ? lane_level(b, l, lf[l], model, h, res) : -1;
  }
  LanePlan plan[L];
  int top = 0;
  bool uniform = true;
  for (int l = 0; l < L; ++l) {
    plan[l] = plan_lane<L>(lev[l], res);
    top = plan[l].fine > top ? plan[l].fine : top;
  }
  for (int l = 0; l < L; ++l) uniform &= plan[l].fine == top && plan[l].coarse == plan[0].coarse;
  if (uniform && plan[0].coarse < 0) {
    advance_at_level<P, L, LD>(levels, top, M, model, lf, src, j, t_s, b);
  } else if (uniform) {
    // Every lane extrapolates from the same two levels (a block in contact together).
    LaneBlock<P, L> coarse;
    copy_block(M, b, coarse);
    advance_at_level<P, L, LD>(levels, plan[0].coarse, M, model, lf, src, j, t_s, coarse);
    advance_at_level<P, L, LD>(levels, top, M, model, lf, src, j, t_s, b);
    for (int l = 0; l < L; ++l) extrapolate_lane(M, lf[l], coarse, l, b);
  } else {
    LaneBlock<P, L> start, run, coarse;
    copy_block(M, b, start);
    copy_block(M, b, coarse);  // every lane that extrapolates overwrites it; the rest keep defined values
    for (int level = 0; level <= top; ++level) {
      bool present = false;
      for (int l = 0; l < L; ++l) present |= plan[l].fine == level || plan[l].coarse == level;
      if (!present) continue;
      copy_block(M, start, run);
      advance_at_level<P, L, LD>(levels, level, M, model, lf, src, j, t_s, run);
      for (int l = 0; l < L; ++l) {
        if (plan[l].fine == level) copy_lane(M, run, l, b);
        if (plan[l].coarse == level) copy_lane(M, run, l, coarse);
      }
    }
    for (int l = 0; l < L; ++l)
      if (plan[l].coarse >= 0) extrapolate_lane(M, lf[l], coarse, l, b);
  }
  for (int l = 0; l < L; ++l) b.zdd[l] = (b.zd[l] - zd0[l]) * inv_h;
}

// The tip's measured signal: the displacement sensor reads the tip relative to the base (z - y);
// an optical lever the slope-weighted sum of the modes.
template <int P, int L>
TIPFORCE_HD void measured_signal(const StepConstants<P>& c, int M, bool displacement, const LaneBlock<P, L>& b,
                                 double* sig) {
  if (displacement) {
    for (int l = 0; l < L; ++l) sig[l] = b.z[l] - b.y[l];
    return;
  }
  for (int l = 0; l < L; ++l) sig[l] = 0.0;
  for (int i = 0; i < M; ++i)
    for (int l = 0; l < L; ++l) sig[l] += c.gain[i] * b.q[i][l];
}

// The block's state at the window's first instant from its modal state (q, v set by the caller).
template <int P, int L>
TIPFORCE_HD void start_block(const StepConstants<P>& c, int M, const LaneForce* lf, const ContactResolution& res,
                             double coarse_h_s, const double* y0, const double* yd0, LaneBlock<P, L>& b) {
  for (int l = 0; l < L; ++l) {
    double u = 0, ud = 0;
    for (int i = 0; i < M; ++i) {
      u += c.phi[i] * b.q[i][l];
      ud += c.phi[i] * b.v[i][l];
    }
    b.y[l] = y0[l];
    b.z[l] = y0[l] + u;
    b.zd[l] = yd0[l] + ud;
    b.zdd[l] = 0.0;
    b.zdd_bound[l] = 0.0;
    b.in[l] = switching(lf[l], b.z[l], b.zd[l]) > 0;
    b.f[l] = branch_force(lf[l], b.in[l], b.z[l], b.zd[l]);
    b.zone[l] = refine_zone(lf[l], res);
    b.linear_level[l] = level_for(lf[l].k, lf[l].model == kKelvinVoigt ? lf[l].c : 0.0, 0.0, coarse_h_s, res);
  }
}

}  // namespace tipforce::detail
