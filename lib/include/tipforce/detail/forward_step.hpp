#pragma once
// The forward solver's per-step arithmetic for a block of L parameter sets, written once for both
// backends: the CPU runs it with L = 8 lanes (the lane loops vectorise across sets), the CUDA
// kernel with L = 1 (one thread per set). lib/src/DESIGN.md has the scheme and its error.
//
// Every step first advances all lanes by the exact free (force-less) update. A lane that is in
// contact, or whose tip may reach the surface within the step (a bound on the tip's path), makes it
// a contact step: the tip-sample force is held as the quadratic through its values at the step's
// start, middle and end, the middle and end values solved implicitly (exponential Lobatto
// collocation, fourth order), in 2^j substeps where the contact is stiff. Lanes whose force law
// changes branch inside a step take the located-crossing step of contact_step.hpp.
#include <cmath>

#include "tipforce/detail/contact_step.hpp"

// The lane loops carry no dependence between lanes; GCC's vectoriser is told so (nvcc and clang
// have no use for the hint).
// The lane loop itself stays a loop (to be vectorised, not unrolled), and the short loops with a
// compile-time count inside it are unrolled first (else the vectoriser sees control flow).
#if defined(__GNUC__) && !defined(__clang__) && !defined(__CUDACC__)
#define TIPFORCE_IVDEP _Pragma("GCC ivdep") _Pragma("GCC unroll 1")
#define TIPFORCE_UNROLL _Pragma("GCC unroll 16")
// A loop over the modes inside a lane loop: whole, for every mode count up to kMaxModes.
#define TIPFORCE_UNROLL_MODES _Pragma("GCC unroll 32")
#else
#define TIPFORCE_IVDEP
#define TIPFORCE_UNROLL
#define TIPFORCE_UNROLL_MODES
#endif

namespace tipforce::detail {

inline constexpr int kMaxModes = 32;
// Substep levels: level j advances a sample period in 2^j steps.
inline constexpr int kSubstepLevels = 11;  // up to 1024 substeps
inline constexpr int kMaxSubsteps = 1 << (kSubstepLevels - 1);

// The force (and a held base acceleration) over a step is held as the quartic through its values
// at the step's five Lobatto points (forward.hpp's kHoldNodes): the start, three inner points and
// the end.
inline constexpr int kPoints = 5;
inline constexpr int kInner = kPoints - 2;
// The k-th point as a fraction of the step (a function: a namespace-scope array is host memory to nvcc).
TIPFORCE_HD double hold_node(int k) {
  constexpr double nodes[kPoints] = {0.0, 0.17267316464601142810, 0.5, 0.82732683535398857190, 1.0};
  return nodes[k];
}

// The tip's response (position z, velocity zd) at the inner points and the end to a unit force held
// as the quartic with value 1 at point k and 0 at the others.
struct TipHoldResponse {
  double z_at[kInner][kPoints], zd_at[kInner][kPoints];
  double z_end[kPoints], zd_end[kPoints];
  // The same for the linear hold from a start to an end value (contact_step's crossing step): a
  // linear function's values at the points are (1 - node) start + node end.
  TIPFORCE_HD TipStepResponse linear() const {
    TipStepResponse r;
    for (int k = 0; k < kPoints; ++k) {
      r.z_start += (1.0 - hold_node(k)) * z_end[k];
      r.z_end += hold_node(k) * z_end[k];
      r.v_start += (1.0 - hold_node(k)) * zd_end[k];
      r.v_end += hold_node(k) * zd_end[k];
    }
    return r;
  }
};

// Per-mode constants of one step length h, indexed by mode; entries past the model's modes are zero
// (so padded modes stay at exactly zero). Plain arrays so that a kernel can take them by value.
template <int P>
struct StepConstants {
  double a00[P], a01[P], a10[P], a11[P];  // transition over h
  double u00[P], u01[P], u10[P], u11[P];  // and back over h (a step undone)
  // phi * the transition back from the end to inner point n: the tip there (position from q, v;
  // velocity from q, v) from the end state.
  double bzq[kInner][P], bzv[kInner][P], bdq[kInner][P], bdv[kInner][P];
  double fq[kPoints][P], fv[kPoints][P];  // (phi / mu L) * response at the end to the force's value at point k
  double gq[kPoints][P], gv[kPoints][P];  // -gamma * the same, for a held base acceleration
  // A held base acceleration's share of the tip at the inner points that the end, reached back,
  // does not carry.
  double gz_at[kInner][kPoints], gzd_at[kInner][kPoints];
  double phi[P], gain[P];                 // tip shape, sensor gain
  double omega[P], zeta[P], gamma[P];     // the modes themselves (a sine drive's steady state)
  double reach[P], inv_omega[P];          // the look-ahead's weight on each mode's amplitude, 1 / omega
  TipHoldResponse tip;
  // The hold's Lagrange basis as polynomials, l_k(u) = sum_p basis[k][p] u^p (u in [0, 1] over the
  // step), and the inverse of its moment matrix M[m][k] = integral of u^m l_k(u): the hold with given
  // moments. And the tip's acceleration per newton of force (a jump in the force jumps it).
  double basis[kPoints][kPoints], moment_inv[kPoints][kPoints];
  double tip_accel_per_n;
  double h_s;
};

// What sizes the contact substeps: mode 1's frequency and the static stiffness give the tip's
// effective mass; `rad_per_substep` is the phase of the contact oscillation one substep may span.
struct ContactResolution {
  double omega1_rad_per_s = 0;
  double k_static_n_per_m = 0;
  double rad_per_substep = 0.3;  // ForwardProblem::contact_rad_per_substep
  // The same for a step in which a lane enters or leaves contact (never coarser than the contact
  // around it; ForwardProblem::crossing_rad_per_substep).
  double crossing_rad_per_substep = 0.1;
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
// velocity and acceleration at the samples (fourth-order differences, lib/src/sampled_base.hpp)
// are interpolated by the cubic through the four samples around t. (Second differences held
// linearly were (omega h)^2 / 6 off in the drive a resonant mode sees: a 1 MHz contact window
// 1.7e-3 off the sine it sampled.)
struct DriveFunction {
  int kind = 0;  // DriveKind value
  double params[4] = {0, 0, 0, 0};
  double t0_s = 0, sample_period_s = 1;
  int n_samples = 0;                       // sampled: the window's samples
  const double* ys = nullptr;              // sampled: samples -1 .. n_samples + 1 (n_samples + 3 values each)
  const double* vs = nullptr;
  const double* as = nullptr;

  TIPFORCE_HD Motion at(double t) const {
    if (kind != 2) return analytic_base_motion(kind, params[0], params[1], params[2], params[3], t);
    double x = (t - t0_s) / sample_period_s;
    x = x < 0 ? 0 : (x > n_samples ? n_samples : x);
    int k = static_cast<int>(x);
    k = k > n_samples - 1 ? n_samples - 1 : k;
    const double u = x - k;
    // Lagrange weights of samples k - 1 .. k + 2 (stored at k .. k + 3).
    const double w0 = -u * (u - 1) * (u - 2) / 6, w1 = (u + 1) * (u - 1) * (u - 2) / 2;
    const double w2 = -(u + 1) * u * (u - 2) / 2, w3 = (u + 1) * u * (u - 1) / 6;
    return {w0 * ys[k] + w1 * ys[k + 1] + w2 * ys[k + 2] + w3 * ys[k + 3],
            w0 * vs[k] + w1 * vs[k + 1] + w2 * vs[k + 2] + w3 * vs[k + 3],
            w0 * as[k] + w1 * as[k + 1] + w2 * as[k + 2] + w3 * as[k + 3]};
  }
};

// The state of L parameter sets. For a sine drive the modal coordinates are the deviation from
// the drive's free steady state (the drive sources below convert at a window's ends); the tip
// position and velocity are always absolute.
template <int P, int L>
struct LaneBlock {
  double q[P][L], v[P][L];
  double f[L], z[L], zd[L];  // force, tip position and velocity at the current instant
  double zs[L], zds[L];      // the tip's smooth part (base, drive response and mode 1) and its velocity
  double reach[L];           // bound on what the other modes add to the tip (their amplitudes only decay in free flight)
  double contact_at[L];      // the tip position (m) from which the force matters: the surface, or the DMT zone
  double gate[L];            // contact_at, or -infinity for a lane in contact (the look-ahead's threshold)
  int linear_level[L];       // spring and Kelvin-Voigt: the substep level of a contact step
  int linear_cross_level[L]; // ... and of a step with a crossing
  int in[L];                 // contact branch (int, not bool, so that the lane loops vectorise)
};

// What the drive gives one (sub)step: the tip's base part (the tip with all modal coordinates zero)
// at the end and the middle, and for a held drive the increments of every mode. LD = 1: shared by
// all lanes.
template <int P, int LD>
struct StepInput {
  double zb1[LD], zbd1[LD];                  // at the end
  double zbn[kInner][LD], zbdn[kInner][LD];  // at the inner points
  double dq[P][LD], dv[P][LD];               // held drives only
};

// The tip and the force at a coarse step's midpoint (node 1/2, the middle of the five hold points),
// where a step that spans two samples puts the odd one (WindowSetup::samples_per_step).
template <int L>
struct MidSample {
  double z[L], f[L];
};

// The tip at inner point n of a step without any force from the end state (b.q, b.v): back from
// the end with the inverse transitions.
template <int P, int L, int LD>
TIPFORCE_HD void free_tip_at(const StepConstants<P>& c, const StepInput<P, LD>& in, const LaneBlock<P, L>& b, int n,
                             double* z) {
  for (int l = 0; l < L; ++l) z[l] = in.zbn[n][LD == 1 ? 0 : l];
  for (int i = 0; i < P; ++i) {
    const double bzq = c.bzq[n][i], bzv = c.bzv[n][i];
TIPFORCE_IVDEP
    for (int l = 0; l < L; ++l) z[l] += bzq * b.q[i][l] + bzv * b.v[i][l];
  }
}

// The held drive of [t, t + h] from a drive function, for one lane slot: the base acceleration at
// the step's points gives each mode's increment and the tip's base part at the inner points.
template <int P, int LD>
TIPFORCE_HD void held_drive_step(const StepConstants<P>& c, const DriveFunction& fn, double t, int lane,
                                 StepInput<P, LD>& in) {
  const double h = c.h_s;
  Motion m[kPoints];
  for (int k = 0; k < kPoints; ++k) m[k] = fn.at(t + hold_node(k) * h);
  for (int i = 0; i < P; ++i) {
    double dq = 0, dv = 0;
    for (int k = 0; k < kPoints; ++k) {
      dq += c.gq[k][i] * m[k].ydd;
      dv += c.gv[k][i] * m[k].ydd;
    }
    in.dq[i][lane] = dq;
    in.dv[i][lane] = dv;
  }
  in.zb1[lane] = m[kPoints - 1].y;
  in.zbd1[lane] = m[kPoints - 1].yd;
  for (int n = 0; n < kInner; ++n) {
    double z = m[n + 1].y, zd = m[n + 1].yd;
    for (int k = 0; k < kPoints; ++k) {
      z += c.gz_at[n][k] * m[k].ydd;
      zd += c.gzd_at[n][k] * m[k].ydd;
    }
    in.zbn[n][lane] = z;
    in.zbdn[n][lane] = zd;
  }
}

// The exact free update of every lane over c.h_s, in place (plus a held drive's increments), and
// the tip at the step's end without any force: zh, zdh (all modes), zs, zds (smooth part).
template <int P, int L, int LD, bool kHeld>
TIPFORCE_HD void free_update(const StepConstants<P>& c, const StepInput<P, LD>& in, LaneBlock<P, L>& b, double* zh,
                             double* zdh, double* zs, double* zds) {
  // Local sums (the outputs may alias nothing, but the vectoriser cannot know that), two of each:
  // the tip's sum over the modes as one chain of P dependent FMAs was the free step's floor (its
  // latency; 1 MHz tapping, one thread, best of 31: 80.5-82.0k -> 89.7-93.3k solves/s, free flight
  // alone 237k -> 327k).
  double z[2][L], zd[2][L];
  for (int l = 0; l < L; ++l) {
    z[0][l] = in.zb1[LD == 1 ? 0 : l];
    zd[0][l] = in.zbd1[LD == 1 ? 0 : l];
    z[1][l] = zd[1][l] = 0.0;
  }
  for (int i = 0; i < P; ++i) {
    const double a00 = c.a00[i], a01 = c.a01[i], a10 = c.a10[i], a11 = c.a11[i], ph = c.phi[i];
    double* z_part = z[i % 2];
    double* zd_part = zd[i % 2];
TIPFORCE_IVDEP
    for (int l = 0; l < L; ++l) {
      double qn = a00 * b.q[i][l] + a01 * b.v[i][l];
      double vn = a10 * b.q[i][l] + a11 * b.v[i][l];
      if constexpr (kHeld) {
        qn += in.dq[i][LD == 1 ? 0 : l];
        vn += in.dv[i][LD == 1 ? 0 : l];
      }
      b.q[i][l] = qn;
      b.v[i][l] = vn;
      z_part[l] += ph * qn;
      zd_part[l] += ph * vn;
    }
  }
  const double ph0 = c.phi[0];
TIPFORCE_IVDEP
  for (int l = 0; l < L; ++l) {
    zh[l] = z[0][l] + z[1][l];
    zdh[l] = zd[0][l] + zd[1][l];
    zs[l] = in.zb1[LD == 1 ? 0 : l] + ph0 * b.q[0][l];
    zds[l] = in.zbd1[LD == 1 ? 0 : l] + ph0 * b.v[0][l];
  }
}

// Undoes free_update (the step is taken again in substeps).
template <int P, int L, int LD, bool kHeld>
TIPFORCE_HD void undo_free_update(const StepConstants<P>& c, const StepInput<P, LD>& in, LaneBlock<P, L>& b) {
  for (int i = 0; i < P; ++i) {
    const double u00 = c.u00[i], u01 = c.u01[i], u10 = c.u10[i], u11 = c.u11[i];
TIPFORCE_IVDEP
    for (int l = 0; l < L; ++l) {
      double q = b.q[i][l], v = b.v[i][l];
      if constexpr (kHeld) {
        q -= in.dq[i][LD == 1 ? 0 : l];
        v -= in.dv[i][LD == 1 ? 0 : l];
      }
      b.q[i][l] = u00 * q + u01 * v;
      b.v[i][l] = u10 * q + u11 * v;
    }
  }
}

// The bound on what the modes other than the first add to the tip: their amplitudes |q| + |v| /
// omega, which only decay in free flight (and mode 1's share the look-ahead's cubic misses).
template <int P, int L>
TIPFORCE_HD void reach_of(const StepConstants<P>& c, const LaneBlock<P, L>& b, double* reach) {
  double r[2][L];  // two partial sums, as in free_update
  for (int l = 0; l < L; ++l) r[0][l] = r[1][l] = 0.0;
  for (int i = 0; i < P; ++i) {
    const double w = c.reach[i], iw = c.inv_omega[i];
    double* ri = r[i % 2];
TIPFORCE_IVDEP
    for (int l = 0; l < L; ++l) ri[l] += w * (fabs(b.q[i][l]) + fabs(b.v[i][l]) * iw);
  }
  for (int l = 0; l < L; ++l) reach[l] = r[0][l] + r[1][l];
}

template <int P, int L>
TIPFORCE_HD void update_reach(const StepConstants<P>& c, LaneBlock<P, L>& b) {
  reach_of(c, b, b.reach);
}

// The highest the smooth part of the tip gets over a step, from its position and velocity at both
// ends: the cubic Hermite through them is at most max(z0, z1) + (4/27) h (zd0+ + zd1-).
TIPFORCE_HD double smooth_peak(double z0, double zd0, double z1, double zd1, double h) {
  const double up = zd0 > 0 ? zd0 : 0.0, down = zd1 < 0 ? -zd1 : 0.0;
  return (z0 > z1 ? z0 : z1) + (4.0 / 27.0) * h * (up + down);
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

// How far below the surface the tip may come before the force law needs the contact step: 0 for the
// repulsive laws; for DMT the gap where the attraction's stiffness reaches its refinement threshold.
TIPFORCE_HD double refine_zone(const LaneForce& lf, const ContactResolution& res) {
  if (lf.model != kDmt && lf.model != kDmtViscous) return 0.0;
  const double g = cbrt(2.0 * lf.hr6 / (kAttractionRefineFraction * res.k_static_n_per_m));
  return g > lf.a0 ? g : lf.a0;
}

// The level whose substep spans at most rad_per_substep of the fastest of: the contact frequency
// with stiffness k added, the damping rate of c, and a transit rate (1/s).
TIPFORCE_HD int level_for(double k_n_per_m, double c_ns_per_m, double transit, double dt_s, const ContactResolution& res,
                          double rad_per_substep) {
  const double m_eff = res.k_static_n_per_m / (res.omega1_rad_per_s * res.omega1_rad_per_s);
  const double rate =
      fmax(fmax(res.omega1_rad_per_s * sqrt(1.0 + k_n_per_m / res.k_static_n_per_m), c_ns_per_m / m_eff), transit);
  const double want = rate * dt_s / rad_per_substep;
  int level = 0;
  while (level < kSubstepLevels - 1 && (1 << level) < want) ++level;
  return level;
}

// Substep level of a Hertzian lane's contact step from the highest penetration its free path
// reaches (pen, m; with the DMT offset) and its speed; the DMT attraction sizes it outside contact.
TIPFORCE_HD int hertzian_level(const LaneForce& lf, int model, double pen, double speed, double dt_s,
                               const ContactResolution& res, double rad_per_substep) {
  double k = 0, c = 0, transit = 0;
  if (pen > 0) {
    contact_stiffness(lf, pen, k, c);
    // The viscous DMT damper grows as sqrt(penetration): it changes on the scale of the
    // penetration itself, which the tip crosses at |zd| / penetration.
    if (model == kDmtViscous) transit = kTransitWeight * speed / fmax(pen, 1e-3 * lf.a0);
  } else if (model == kDmt || model == kDmtViscous) {
    // Out of contact the DMT attraction H R / (6 d^2) varies on the length scale of the gap d
    // itself: the tip crosses it at the rate |zd| / d, far faster than any oscillation, and its
    // stiffness H R / (3 d^3) at the nearest gap says whether that matters.
    const double gap = fmax(lf.a0 - pen, lf.a0);
    k = 2.0 * lf.hr6 / (gap * gap * gap);
    if (k < kAttractionRefineFraction * res.k_static_n_per_m) return 0;
    transit = kTransitWeight * speed / gap;
  }
  return level_for(k, c, transit, dt_s, res, rad_per_substep);
}

// One branch's force and its derivatives in the tip position and velocity. Plain selects, no
// branches or library calls (fmax, fmin), so that the lane loops that call it vectorise.
struct ForceSlope {
  double f, fz, fzd;
};

// A block's force laws, one array per constant (structure of arrays: the lane loops vectorise).
template <int L>
struct LaneLaws {
  double k[L], c[L], h[L], big_k[L], hr6[L], a0[L], eta_sqrt_r[L], f0[L];
  TIPFORCE_HD explicit LaneLaws(const LaneForce* lf) {
    for (int l = 0; l < L; ++l) {
      k[l] = lf[l].k;
      c[l] = lf[l].c;
      h[l] = lf[l].h;
      big_k[l] = lf[l].big_k;
      hr6[l] = lf[l].hr6;
      a0[l] = lf[l].a0;
      eta_sqrt_r[l] = lf[l].eta_sqrt_r;
      f0[l] = lf[l].f0;
    }
  }
};

// Every constant is loaded whatever the branch (a load under a condition keeps the loop scalar)
// and the branch selects by arithmetic.
template <int kModel, int L>
TIPFORCE_HD ForceSlope force_slope(const LaneLaws<L>& p, int l, bool in, double z, double zd) {
  const double on = in ? 1.0 : 0.0;
  if constexpr (kModel == kSpring) {
    const double k = on * p.k[l];
    return {-k * (z - p.h[l]), -k, 0.0};
  } else if constexpr (kModel == kKelvinVoigt) {
    // The branch's law, unclipped: where it would pull, the switching function says it left.
    const double k = on * p.k[l], c = on * p.c[l];
    return {-k * (z - p.h[l]) - c * zd, -k, -c};
  } else if constexpr (kModel == kHertz) {
    const double d = z - p.h[l], pen = on * (d > 0 ? d : 0.0), sq = sqrt(pen), bk = p.big_k[l];
    return {-bk * pen * sq, -1.5 * bk * sq, 0.0};
  } else if constexpr (kModel == kDmt || kModel == kDmtViscous) {
    // Out of contact the attraction H R / (6 d^2), d >= a0; in contact DMT's law.
    const double a0 = p.a0[l], hr6 = p.hr6[l], bk = p.big_k[l], f0 = p.f0[l], eta = p.eta_sqrt_r[l];
    const double gap = p.h[l] - z, far = gap > a0 ? 1.0 : 0.0, dd = gap > a0 ? gap : a0;  // dd >= a0 > 0
    const double fa = hr6 / (dd * dd), fza = far * 2.0 * hr6 / (dd * dd * dd);
    const double d = a0 - gap, pen = d > 0 ? d : 0.0, sq = sqrt(pen);
    double fc = f0 - bk * pen * sq, fzc = -1.5 * bk * sq, fzdc = 0.0;
    if constexpr (kModel == kDmtViscous) {
      fc -= eta * sq * zd;
      fzdc = -eta * sq;
      fzc -= (sq > 0 ? 1.0 : 0.0) * eta * zd * 0.5 / (sq > 0 ? sq : 1.0);
    }
    return {on * fc + (1 - on) * fa, on * fzc + (1 - on) * fza, on * fzdc};
  } else {
    return {0.0, 0.0, 0.0};
  }
}

template <int kModel, int L>
TIPFORCE_HD double switching_vec(const LaneLaws<L>& p, int l, double z, double zd) {
  const double delta = z - p.h[l];
  if constexpr (kModel == kSpring || kModel == kHertz) {
    return delta;
  } else if constexpr (kModel == kKelvinVoigt) {
    const double a = p.k[l] * delta, b = a + p.c[l] * zd;
    return a < b ? a : b;
  } else if constexpr (kModel == kDmt || kModel == kDmtViscous) {
    return delta + p.a0[l];
  } else {
    return -1.0;
  }
}

// Whether a law (its force and its switching function) depends on the tip's velocity. The spring's
// and Hertz's do not: their contact steps skip the tip velocity at the hold's inner points (half of
// the backward transitions) and locate a crossing from the position's quartic alone, its
// derivative the Newton slope. (The velocity at the step's end is still the state's.)
template <int kModel>
inline constexpr bool kUsesVelocity = !(kModel == kSpring || kModel == kHertz);

// The branch's force, as branch_force (contact_step.hpp) but vectorisable over lanes: force_slope's,
// with Kelvin-Voigt's clipped (it never pulls).
template <int kModel, int L>
TIPFORCE_HD double branch_force_vec(const LaneLaws<L>& p, int l, bool in, double z, double zd) {
  const double f = force_slope<kModel>(p, l, in, z, zd).f;
  if constexpr (kModel == kKelvinVoigt) return f < 0.0 ? f : 0.0;
  return f;
}

// The tip's position and velocity at unknown point j (the inner points, then the end) per unit force
// at unknown point k + 1 of the hold.
TIPFORCE_HD double hold_z(const TipHoldResponse& t, int j, int k) { return j < kInner ? t.z_at[j][k + 1] : t.z_end[k + 1]; }
TIPFORCE_HD double hold_zd(const TipHoldResponse& t, int j, int k) { return j < kInner ? t.zd_at[j][k + 1] : t.zd_end[k + 1]; }

inline constexpr int kUnknowns = kPoints - 1;  // the force at the inner points and the end

// The force law on branch in_p at each unknown point of a path (zk, zdk at the inner points and
// the end): the linear collocation's right-hand side, and the weak attraction's explicit hold.
template <int kModel, int L>
TIPFORCE_HD void forces_along(const LaneLaws<L>& laws, const double* in_p, const double (*zk)[L],
                              const double (*zdk)[L], double (*f_out)[L]) {
TIPFORCE_IVDEP
  for (int l = 0; l < L; ++l) {
    TIPFORCE_UNROLL
    for (int j = 0; j < kUnknowns; ++j) f_out[j][l] = force_slope<kModel>(laws, l, in_p[l] > 0, zk[j][l], zdk[j][l]).f;
  }
}

// For the linear laws (spring, Kelvin-Voigt) the collocation is one linear solve whose matrix,
// I + k T_z + c T_zd (T the hold's responses at the points), depends only on the lane's law and the
// substep level: a block of kLanes keeps its inverse per level (a window uses two or three levels)
// and collocates by a matrix-vector product. A lane of one (the GPU's thread, and its host
// emulation) eliminates each time: the cache would live in local memory there.
inline constexpr int kCachedLevels = 4;
template <int L>
struct CollocationCache {
  static constexpr bool kEnabled = true;
  const TipHoldResponse* level[kCachedLevels] = {};
  int next = 0;
  double inv[kCachedLevels][kUnknowns][kUnknowns][L];
};
template <>
struct CollocationCache<1> {
  static constexpr bool kEnabled = false;
};

// The inverse of every lane's linear collocation matrix in contact, I + k T_z + c T_zd (Gauss-Jordan
// without pivoting: the identity plus the contact's share, as in lobatto_block).
template <int kModel, int L>
TIPFORCE_HD_OUTLINE void linear_collocation_inverse(const LaneLaws<L>& laws, const TipHoldResponse& t,
                                                    double (*inv)[kUnknowns][L]) {
  constexpr int U = kUnknowns;
  double a[U][U][L];
  for (int l = 0; l < L; ++l) {
    const double kz = laws.k[l], cz = kModel == kKelvinVoigt ? laws.c[l] : 0.0;
    for (int j = 0; j < U; ++j)
      for (int k = 0; k < U; ++k) {
        a[j][k][l] = (j == k ? 1.0 : 0.0) + kz * hold_z(t, j, k) + cz * hold_zd(t, j, k);
        inv[j][k][l] = j == k ? 1.0 : 0.0;
      }
  }
  for (int c = 0; c < U; ++c)
    for (int l = 0; l < L; ++l) {
      const double d = 1.0 / a[c][c][l];
      for (int k = 0; k < U; ++k) {
        a[c][k][l] *= d;
        inv[c][k][l] *= d;
      }
      for (int j = 0; j < U; ++j) {
        if (j == c) continue;
        const double m = a[j][c][l];
        for (int k = 0; k < U; ++k) {
          a[j][k][l] -= m * a[c][k][l];
          inv[j][k][l] -= m * inv[c][k][l];
        }
      }
    }
}

// The Lobatto collocation of every lane's force on its current branch: its values f[j] at the
// step's inner points and end with f = F(z, zd) there, where z and zd are affine in those unknowns
// (zk, zdk the parts that do not depend on them). Newton in the four unknowns, all lanes at once:
// one iteration is exact for the linear laws. ok[l] = 0 where a lane did not converge.
template <int kModel, int L>
TIPFORCE_HD_OUTLINE void lobatto_block(const LaneLaws<L>& laws, const double* in_p, const TipHoldResponse& t,
                                       const double (*zk_p)[L], const double (*zdk_p)[L], const double* f0,
                                       double (*f_out)[L], int* ok, CollocationCache<L>& cache) {
  constexpr bool kLinear = kModel == kSpring || kModel == kKelvinVoigt;
  if constexpr (kLinear && CollocationCache<L>::kEnabled) {
    // f = (I + k T_z + c T_zd)^-1 F(free path) in contact; out of contact F and so f are zero.
    int e = 0;
    while (e < kCachedLevels && cache.level[e] != &t) ++e;
    if (e == kCachedLevels) {
      e = cache.next;
      cache.next = (cache.next + 1) % kCachedLevels;
      cache.level[e] = &t;
      linear_collocation_inverse<kModel, L>(laws, t, cache.inv[e]);
    }
    const double (*inv)[kUnknowns][L] = cache.inv[e];
    double fz[kUnknowns][L];
    forces_along<kModel, L>(laws, in_p, zk_p, zdk_p, fz);
TIPFORCE_IVDEP
    for (int l = 0; l < L; ++l) {
      double sum = 0;
      TIPFORCE_UNROLL
      for (int j = 0; j < kUnknowns; ++j) {
        double x = 0;
        TIPFORCE_UNROLL
        for (int k = 0; k < kUnknowns; ++k) x += inv[j][k][l] * fz[k][l];
        f_out[j][l] = x;
        sum += x;
      }
      ok[l] = static_cast<int>(sum == sum);
    }
    return;
  }
  (void)cache;
  constexpr int kMaxIterations = kLinear ? 1 : 30;
  constexpr int U = kUnknowns;
  // Local copies: the vectoriser cannot rule out that the pointers alias one another.
  double zk[U][L], zdk[U][L], in[L], f[U][L];
  for (int j = 0; j < U; ++j)
    for (int l = 0; l < L; ++l) {
      zk[j][l] = zk_p[j][l];
      zdk[j][l] = zdk_p[j][l];
    }
  for (int l = 0; l < L; ++l) in[l] = in_p[l];
  double tz[U][U], tv[U][U];
  for (int j = 0; j < U; ++j)
    for (int k = 0; k < U; ++k) {
      tz[j][k] = hold_z(t, j, k);
      tv[j][k] = hold_zd(t, j, k);
    }
  for (int j = 0; j < U; ++j)
    for (int l = 0; l < L; ++l) f[j][l] = kLinear ? 0.0 : f0[l];
  double change[L], size[L];
  for (int it = 0; it < kMaxIterations; ++it) {
    // One Newton iteration per lane, the 4 x 4 system built and solved in the same lane loop (every
    // inner loop unrolled, so that the lane loop vectorises and the matrix stays in registers;
    // with the elimination's loops outside the lanes GCC vectorised two lanes at a time, and the
    // back substitution not at all: three quarters of a DMT solve).
TIPFORCE_IVDEP
    for (int l = 0; l < L; ++l) {
      double a[U][U], r[U];
      TIPFORCE_UNROLL
      for (int j = 0; j < U; ++j) {
        double z = zk[j][l], zd = zdk[j][l];
        TIPFORCE_UNROLL
        for (int k = 0; k < U; ++k) {
          z += tz[j][k] * f[k][l];
          zd += tv[j][k] * f[k][l];
        }
        const ForceSlope s = force_slope<kModel>(laws, l, in[l] > 0, z, zd);
        r[j] = f[j][l] - s.f;
        TIPFORCE_UNROLL
        for (int k = 0; k < U; ++k) a[j][k] = (j == k ? 1.0 : 0.0) - s.fz * tz[j][k] - s.fzd * tv[j][k];
      }
      // Gaussian elimination: the matrix is the identity plus the contact's share (no pivoting).
      double pivot_inv[U];
      TIPFORCE_UNROLL
      for (int c = 0; c < U; ++c) {
        pivot_inv[c] = 1.0 / a[c][c];
        TIPFORCE_UNROLL
        for (int j = c + 1; j < U; ++j) {
          const double m = a[j][c] * pivot_inv[c];
          TIPFORCE_UNROLL
          for (int k = c + 1; k < U; ++k) a[j][k] -= m * a[c][k];
          r[j] -= m * r[c];
        }
      }
      double ch = 0.0, sz = 0.0;
      TIPFORCE_UNROLL
      for (int c = U - 1; c >= 0; --c) {
        double x = r[c];
        TIPFORCE_UNROLL
        for (int k = c + 1; k < U; ++k) x -= a[c][k] * r[k];
        x *= pivot_inv[c];
        r[c] = x;
        const double fc = f[c][l] - x;
        f[c][l] = fc;
        ch += x < 0 ? -x : x;
        sz += fc < 0 ? -fc : fc;
      }
      change[l] = ch;
      size[l] = sz;
    }
    if (kLinear) break;
    int done = 1;
    for (int l = 0; l < L; ++l) done &= static_cast<int>(change[l] <= 1e-13 * size[l] + 1e-300);
    if (done) break;
  }
  for (int l = 0; l < L; ++l) {
    double sum = 0;
    for (int j = 0; j < U; ++j) {
      sum += f[j][l];
      f_out[j][l] = f[j][l];
    }
    ok[l] = static_cast<int>(sum == sum) & static_cast<int>(kLinear || change[l] <= 1e-13 * size[l] + 1e-300);
  }
}

// A quartic's value at u from lane l's monomial coefficients a[p][l] (Horner).
template <int L>
TIPFORCE_HD double quartic_at(const double (*a)[L], int l, double u) {
  double v = 0;
  TIPFORCE_UNROLL
  for (int p = kPoints - 1; p >= 0; --p) v = v * u + a[p][l];
  return v;
}

// The step of the lanes whose force law changes branch inside it (contact onset or release). Up to
// the crossing the old branch governs the motion: its collocated trajectory (the tip at the hold's
// points) gives the switching function as a quartic in u in [0, 1], whose root is the crossing
// theta. The force is the old branch's hold on [0, theta]; after it, the new branch's law along the
// old trajectory plus a correction that grows as the cube of the time since the crossing (the new
// force's own effect on the tip; as its square for Kelvin-Voigt, whose damper makes the force jump),
// its size fixed by the step-end force, which is solved implicitly. That piecewise force is replaced
// by the quartic hold with the same first five moments (exact in its effect on every mode that turns
// little over the step).
// Every lane with use[l] set at once: zp, zdp its old branch's tip at the hold's points, g on entry
// that branch's hold (its force at the points), in0 its branch at the start. Where a crossing is
// found on the old trajectory (found[l]), g and f_end become the crossing step's hold and step-end
// force; elsewhere they are left as they are. The lanes are vector code (a crossing step has 4 to
// 6 of 8 lanes crossing at 1 MHz, and one lane at a time this was a quarter of the solve); only the
// step-end force is solved per lane.
template <int kModel, int P, int L>
TIPFORCE_HD_OUTLINE void located_crossings(const StepConstants<P>& c, const LaneLaws<L>& laws, const LaneForce* lf,
                                           const int* use, const int* in0, const double (*zp)[L],
                                           const double (*zdp)[L], const double* zh, const double* zdh,
                                           double (*g)[L], double* f_end, int* found) {
  const TipHoldResponse& t = c.tip;
  const double h = c.h_s;
  // The bracket: the first point at which the switching function has left the old branch's sign.
  // (Selects, no branches or divisions under a condition, so that the lane loops vectorise.)
  double lo[L], hi[L], theta[L];
  int lo_side[L], active[L];
TIPFORCE_IVDEP
  for (int l = 0; l < L; ++l) {
    double s[kPoints];
    TIPFORCE_UNROLL
    for (int j = 0; j < kPoints; ++j) s[j] = switching_vec<kModel>(laws, l, zp[j][l], zdp[j][l]);
    const bool was_in = in0[l] != 0;
    double a = 0, b = 1, s_lo = 0, s_hi = -1;
    int flipped = 0;
    TIPFORCE_UNROLL
    for (int j = kPoints - 1; j >= 1; --j) {
      const bool flip = (s[j] > 0) != was_in;
      a = flip ? hold_node(j - 1) : a;
      b = flip ? hold_node(j) : b;
      s_lo = flip ? s[j - 1] : s_lo;
      s_hi = flip ? s[j] : s_hi;
      flipped |= static_cast<int>(flip);
    }
    found[l] = use[l] & flipped;
    lo[l] = a;
    hi[l] = b;
    lo_side[l] = s_lo > 0;
    theta[l] = a + (b - a) * s_lo / (s_lo - s_hi);
    active[l] = found[l];
  }
  // zdp is read only where the law uses the velocity (kUsesVelocity); else azd stays zero.
  constexpr bool kVelocity = kUsesVelocity<kModel>;
  double az[kPoints][L], azd[kPoints][L], af[kPoints][L];
  for (int q = 0; q < kPoints; ++q)
TIPFORCE_IVDEP
    for (int l = 0; l < L; ++l) {
      double a = 0, ad = 0, fa = 0;
      TIPFORCE_UNROLL
      for (int k = 0; k < kPoints; ++k) {
        a += zp[k][l] * c.basis[k][q];
        if constexpr (kVelocity) ad += zdp[k][l] * c.basis[k][q];
        fa += g[k][l] * c.basis[k][q];
      }
      az[q][l] = a;
      azd[q][l] = ad;
      af[q][l] = fa;
    }
  // The root in the bracket: Newton on the quartics, kept inside it (where a step would leave it,
  // bisection). The switching function is the tip's position (less the surface) for every law but
  // Kelvin-Voigt's, the smaller of k delta and k delta + c zd.
  for (int it = 0; it < 12; ++it) {
    int any = 0;
TIPFORCE_IVDEP
    for (int l = 0; l < L; ++l) {
      const double th = theta[l];
      const double z = quartic_at<L>(az, l, th), zd = kVelocity ? quartic_at<L>(azd, l, th) : 0.0;
      double zdd_u = 0;
      if constexpr (kModel == kKelvinVoigt) {
        TIPFORCE_UNROLL
        for (int p = kPoints - 1; p >= 1; --p) zdd_u = zdd_u * th + p * azd[p][l];  // d(zd)/du
      }
      const double st = switching_vec<kModel>(laws, l, z, zd);
      const bool side = static_cast<int>(st > 0) == lo_side[l];
      const double nlo = side ? th : lo[l], nhi = side ? hi[l] : th;
      double slope;  // d(z - h)/du
      if constexpr (kModel == kKelvinVoigt) {
        slope = laws.k[l] * zd * h + (zd < 0 ? laws.c[l] * zdd_u : 0.0);
      } else if constexpr (kVelocity) {
        slope = zd * h;
      } else {
        slope = 0;
        TIPFORCE_UNROLL
        for (int p = kPoints - 1; p >= 1; --p) slope = slope * th + p * az[p][l];
      }
      const double step = st / (slope != 0 ? slope : 1.0);
      double next = slope != 0 ? th - step : 0.5 * (nlo + nhi);
      const int newton = static_cast<int>(next > nlo) & static_cast<int>(next < nhi);
      next = newton ? next : 0.5 * (nlo + nhi);
      // Near a simple root Newton's error after a step of size c is ~c^2 (the quartic's curvature
      // and slope are O(1) in u), so a Newton step of 1e-7 leaves theta within ~1e-14 of the step;
      // at a grazing (double) root, where Newton converges only linearly, the switching function is
      // flat and theta's error moves nothing. (A bisection step says only that the root is in the
      // bracket: that stops at 1e-12.) Stopping Newton at 1e-12 took one iteration more for
      // nothing, and up to 12 at grazing crossings: 1 MHz spring tapping, one thread, best of 15,
      // 26.6-27.0k -> 28.7-29.8k solves/s.
      const double change = next - th;
      const int stop = (newton & static_cast<int>(fabs(change) < 1e-7)) | static_cast<int>(nhi - nlo < 1e-12);
      const int a = active[l];
      theta[l] = a ? next : th;
      lo[l] = a ? nlo : lo[l];
      hi[l] = a ? nhi : hi[l];
      active[l] = a & (1 - stop);
      any |= active[l];
    }
    if (!any) break;
  }
  constexpr double gx[5] = {0.04691007703066800, 0.23076534494715845, 0.5, 0.76923465505284155, 0.95308992296933200};
  constexpr double gw[5] = {0.11846344252809454, 0.23931433524968324, 0.28444444444444444, 0.23931433524968324,
                            0.11846344252809454};
  // Moments m_k = integral of u^k f(u): a constant part and a part per unit of the step-end force.
  constexpr double binom[kPoints][kPoints] = {{1, 0, 0, 0, 0}, {1, 1, 0, 0, 0}, {1, 2, 1, 0, 0}, {1, 3, 3, 1, 0},
                                              {1, 4, 6, 4, 1}};
  // 1/n, so that the moments' loops multiply: divisions were a third of this step's time.
  constexpr double inv[2 * kPoints] = {0.0,       1.0,       1.0 / 2.0, 1.0 / 3.0, 1.0 / 4.0,
                                       1.0 / 5.0, 1.0 / 6.0, 1.0 / 7.0, 1.0 / 8.0, 1.0 / 9.0};
  double zA[L], zB[L], vA[L], vB[L], gc[kPoints][L], gf[kPoints][L];
TIPFORCE_IVDEP
  for (int l = 0; l < L; ++l) {
    const bool in1 = in0[l] == 0;
    // (Kelvin-Voigt's force jumps at onset only: it leaves contact where its force comes to zero.)
    const bool square = kModel == kKelvinVoigt && in1;
    const double th = theta[l], om = 1.0 - th;
    const double f_pred_end = branch_force_vec<kModel>(laws, l, in1, zp[kPoints - 1][l], zdp[kPoints - 1][l]);
    double fq[5], uq[5];
    TIPFORCE_UNROLL
    for (int q = 0; q < 5; ++q) {
      uq[q] = th + om * gx[q];
      fq[q] = branch_force_vec<kModel>(laws, l, in1, quartic_at<L>(az, l, uq[q]), quartic_at<L>(azd, l, uq[q])) *
              gw[q] * om;
    }
    double tpow[2 * kPoints + 1], opow[kPoints];
    tpow[0] = 1;
    TIPFORCE_UNROLL
    for (int q = 1; q <= 2 * kPoints; ++q) tpow[q] = tpow[q - 1] * th;
    opow[0] = 1;
    TIPFORCE_UNROLL
    for (int q = 1; q < kPoints; ++q) opow[q] = opow[q - 1] * om;
    double mc[kPoints], mf[kPoints], upow[5];
    TIPFORCE_UNROLL
    for (int q = 0; q < 5; ++q) upow[q] = 1.0;
    TIPFORCE_UNROLL
    for (int m = 0; m < kPoints; ++m) {
      double old = 0;
      TIPFORCE_UNROLL
      for (int q = 0; q < kPoints; ++q) old += af[q][l] * tpow[q + m + 1] * inv[q + m + 1];
      double pred = 0;
      TIPFORCE_UNROLL
      for (int q = 0; q < 5; ++q) {
        pred += fq[q] * upow[q];
        upow[q] *= uq[q];
      }
      double corr = 0;
      TIPFORCE_UNROLL
      for (int r = 0; r <= m; ++r) corr += binom[m][r] * tpow[m - r] * opow[r] * (square ? inv[r + 3] : inv[r + 4]);
      corr *= om;
      mc[m] = old + pred - f_pred_end * corr;
      mf[m] = corr;
    }
    double za = zh[l], zb = 0, va = zdh[l], vb = 0;
    TIPFORCE_UNROLL
    for (int k = 0; k < kPoints; ++k) {
      double a = 0, b = 0;
      TIPFORCE_UNROLL
      for (int m = 0; m < kPoints; ++m) {
        a += c.moment_inv[k][m] * mc[m];
        b += c.moment_inv[k][m] * mf[m];
      }
      gc[k][l] = a;
      gf[k][l] = b;
      za += t.z_end[k] * a;
      zb += t.z_end[k] * b;
      va += t.zd_end[k] * a;
      vb += t.zd_end[k] * b;
    }
    zA[l] = za;
    zB[l] = zb;
    vA[l] = va;
    vB[l] = vb;
  }
  for (int l = 0; l < L; ++l) {
    if (!found[l]) continue;
    const double fe = solve_branch(lf[l], in0[l] == 0, zA[l], zB[l], vA[l], vB[l]);
    found[l] = fe == fe;
    if (!found[l]) continue;
    f_end[l] = fe;
    for (int k = 0; k < kPoints; ++k) g[k][l] = gc[k][l] + gf[k][l] * fe;
  }
}

// How a contact step's hold is found: collocated (implicit, Newton), or explicitly, the force law
// along the path without the unknown forces (forces_along), where every lane stays where the DMT
// attraction is weak (its stiffness below kAttractionRefineFraction of the cantilever's: the
// look-ahead's bound says so). The implicit solve would move each value by that stiffness times
// the tip's compliance over the step, which with every mode counted is ~0.04 (1e-6 s) to ~0.1
// (2e-6 s) of the static one for the paper's cantilever: a few 1e-5 of the attraction, itself a
// small part of the signal (lib/src/DESIGN.md, the look-ahead). Newton's iterations there were
// most of a DMT solve.
enum class HoldSolve { collocated, weak_attraction };

// Finishes a contact step from the free update (b.q, b.v already advanced; zh, zdh the tip at the
// end without force): each lane's force over the step, held as a quartic, and its response added.
// z, zd, f and the branch in b are the step start's. With allow_cross false it changes nothing and
// returns false when a lane's branch would change inside the step (the caller takes the step again
// more finely, as crossings need); else true. hold: collocated, or the weak attraction's explicit
// hold (the caller's look-ahead vouches for it).
// mid (when not null) receives the tip and the force at the step's midpoint. halves (when not null)
// receives, when the step is refused for a crossing, in which halves of it the crossing lanes'
// branches change (bit 0 the first, bit 1 the second; both where the collocation failed).
template <int kModel, int P, int L, int LD>
TIPFORCE_HD_OUTLINE bool contact_finish(const StepConstants<P>& c, const LaneForce* lf, const StepInput<P, LD>& in,
                                const double* zh, const double* zdh, bool allow_cross, HoldSolve hold,
                                LaneBlock<P, L>& b, CollocationCache<L>& cache, MidSample<L>* mid,
                                int* halves = nullptr) {
  constexpr int U = kUnknowns;
  // The tip at the inner points without force: back from the end.
  double zk[U][L], zdk[U][L];
  for (int n = 0; n < kInner; ++n)
    for (int l = 0; l < L; ++l) {
      zk[n][l] = in.zbn[n][LD == 1 ? 0 : l];
      zdk[n][l] = in.zbdn[n][LD == 1 ? 0 : l];
    }
  // A law without the velocity (kUsesVelocity) leaves the inner points' zdk, and so zdp below, at
  // the base's part: every use of them ignores them.
  for (int i = 0; i < P; ++i) {
    for (int n = 0; n < kInner; ++n) {
      const double bzq = c.bzq[n][i], bzv = c.bzv[n][i], bdq = c.bdq[n][i], bdv = c.bdv[n][i];
TIPFORCE_IVDEP
      for (int l = 0; l < L; ++l) {
        zk[n][l] += bzq * b.q[i][l] + bzv * b.v[i][l];
        if constexpr (kUsesVelocity<kModel>) zdk[n][l] += bdq * b.q[i][l] + bdv * b.v[i][l];
      }
    }
  }
  const TipHoldResponse& t = c.tip;
  double z_mid_free[L], zd_mid_free[L];
  for (int l = 0; l < L; ++l) {
    z_mid_free[l] = zk[1][l];
    zd_mid_free[l] = zdk[1][l];
  }
  // Add the start force's share: zk, zdk become what does not depend on the unknowns.
TIPFORCE_IVDEP
  for (int l = 0; l < L; ++l) {
    TIPFORCE_UNROLL
    for (int n = 0; n < kInner; ++n) {
      zk[n][l] += t.z_at[n][0] * b.f[l];
      zdk[n][l] += t.zd_at[n][0] * b.f[l];
    }
    zk[kInner][l] = zh[l] + t.z_end[0] * b.f[l];
    zdk[kInner][l] = zdh[l] + t.zd_end[0] * b.f[l];
  }
  const LaneLaws<L> laws(lf);
  double f[U][L], in0[L];
  int ok[L];
  for (int l = 0; l < L; ++l) in0[l] = b.in[l] ? 1.0 : -1.0;
  constexpr bool kAttracts = kModel == kDmt || kModel == kDmtViscous;  // (the other laws compile without it)
  if (kAttracts && hold == HoldSolve::weak_attraction) {
    forces_along<kModel, L>(laws, in0, zk, zdk, f);
    for (int l = 0; l < L; ++l) ok[l] = 1;
  } else {
    lobatto_block<kModel, L>(laws, in0, t, zk, zdk, b.f, f, ok, cache);
  }
  // The branch must hold at every point (the switching function keeps its sign, that of in0);
  // else the lane crosses inside the step.
  double tz[U][U], tv[U][U];
  for (int j = 0; j < U; ++j)
    for (int k = 0; k < U; ++k) {
      tz[j][k] = hold_z(t, j, k);
      tv[j][k] = hold_zd(t, j, k);
    }
  // The collocated trajectory at the points (the old branch's, should a lane cross).
  double worst[L], by_mid[L], at_end[L], zp[kPoints][L], zdp[kPoints][L];
  for (int l = 0; l < L; ++l) {
    worst[l] = ok[l] ? 1.0 : -1.0;
    zp[0][l] = b.z[l];
    zdp[0][l] = b.zd[l];
  }
  for (int j = 0; j < U; ++j)
TIPFORCE_IVDEP
    for (int l = 0; l < L; ++l) {
      double z = zk[j][l], zd = zdk[j][l];
      TIPFORCE_UNROLL
      for (int k = 0; k < U; ++k) {
        z += tz[j][k] * f[k][l];
        if constexpr (kUsesVelocity<kModel>) zd += tv[j][k] * f[k][l];
      }
      zp[j + 1][l] = z;
      zdp[j + 1][l] = zd;
      const double agree = switching_vec<kModel>(laws, l, z, zd) * in0[l];
      worst[l] = agree < worst[l] ? agree : worst[l];
      if (j == 1) by_mid[l] = worst[l];  // point 2 is node 1/2
      at_end[l] = agree;
    }
  int cross[L], any_cross = 0;
  for (int l = 0; l < L; ++l) {
    cross[l] = static_cast<int>(!(worst[l] > 0));
    any_cross |= cross[l];
  }
  if (any_cross && !allow_cross) {
    if (halves) {
      // Changed by the middle: the first half; back by the end, or changed only after it: the second.
      int m = 0;
      for (int l = 0; l < L; ++l)
        if (cross[l]) m |= !ok[l] ? 3 : !(by_mid[l] > 0) ? (at_end[l] > 0 ? 3 : 1) : 2;
      *halves = m;
    }
    return false;
  }
  double g[kPoints][L], f_end[L];
  int in_end[L];
  for (int l = 0; l < L; ++l) {
    g[0][l] = b.f[l];
    for (int k = 1; k < kPoints; ++k) g[k][l] = f[k - 1][l];
    f_end[l] = f[U - 1][l];
    in_end[l] = b.in[l];
  }
  if (any_cross) {
    int use[L], found[L];
    for (int l = 0; l < L; ++l) use[l] = cross[l] & ok[l];
    located_crossings<kModel, P, L>(c, laws, lf, use, b.in, zp, zdp, zh, zdh, g, f_end, found);
    for (int l = 0; l < L; ++l)
      if (found[l]) in_end[l] = b.in[l] ? 0 : 1;
    for (int l = 0; l < L; ++l) {
      if (!cross[l] || found[l]) continue;
      // No usable old trajectory (its collocation did not converge): the linear hold of
      // contact_step.hpp, from the step's ends alone.
      const TipStepResponse lin = t.linear();
      const double f0 = b.f[l];
      const double zhat = zh[l] + (lin.z_start + lin.z_end) * f0, zdhat = zdh[l] + (lin.v_start + lin.v_end) * f0;
      const ContactResult r = contact_step(lf[l], lin, zhat, zdhat, b.z[l], b.zd[l], f0, b.in[l] != 0);
      const double start = f0 + r.beta, end = r.alpha;
      for (int k = 0; k < kPoints; ++k) g[k][l] = start + (end - start) * hold_node(k);
      f_end[l] = r.f;
      in_end[l] = r.in ? 1 : 0;
    }
  }
  // In free flight every hold is zero: lanes carried through a contact step need no correction.
  int any = 0;
  for (int k = 0; k < kPoints; ++k)
    for (int l = 0; l < L; ++l) any |= static_cast<int>(g[k][l] != 0.0);
  if (any) {
    for (int i = 0; i < P; ++i) {
      double fq[kPoints], fv[kPoints];
      for (int k = 0; k < kPoints; ++k) {
        fq[k] = c.fq[k][i];
        fv[k] = c.fv[k][i];
      }
TIPFORCE_IVDEP
      for (int l = 0; l < L; ++l) {
        double dq = 0, dv = 0;
        TIPFORCE_UNROLL
        for (int k = 0; k < kPoints; ++k) {
          dq += fq[k] * g[k][l];
          dv += fv[k] * g[k][l];
        }
        b.q[i][l] += dq;
        b.v[i][l] += dv;
      }
    }
  }
TIPFORCE_IVDEP
  for (int l = 0; l < L; ++l) {
    double z = zh[l], zd = zdh[l];
    TIPFORCE_UNROLL
    for (int k = 0; k < kPoints; ++k) {
      z += t.z_end[k] * g[k][l];
      zd += t.zd_end[k] * g[k][l];
    }
    b.z[l] = z;
    b.zd[l] = zd;
    b.f[l] = f_end[l];
    b.in[l] = in_end[l];
  }
  if (mid)
    for (int l = 0; l < L; ++l) {
      double z = z_mid_free[l];
      TIPFORCE_UNROLL
      for (int k = 0; k < kPoints; ++k) z += t.z_at[1][k] * g[k][l];
      mid->z[l] = z;
      // Collocated, the hold's middle value is the force law there. A crossing lane's hold stands
      // for the piecewise force only in its moments: the law at the middle's state, on the branch
      // that state is on (else a spring's onset shows half a step's force before the contact).
      if (!cross[l]) {
        mid->f[l] = g[2][l];
        continue;
      }
      double zd = zd_mid_free[l];
      if constexpr (kUsesVelocity<kModel>) {
        TIPFORCE_UNROLL
        for (int k = 0; k < kPoints; ++k) zd += t.zd_at[1][k] * g[k][l];
      }
      mid->f[l] = branch_force(lf[l], switching(lf[l], z, zd) > 0, z, zd);
    }
  return true;
}

// contact_finish for the model, a run-time value.
template <int P, int L, int LD>
TIPFORCE_HD bool contact_finish_any(int model, const StepConstants<P>& c, const LaneForce* lf, const StepInput<P, LD>& in,
                                    const double* zh, const double* zdh, bool allow_cross, HoldSolve hold,
                                    LaneBlock<P, L>& b, CollocationCache<L>& cache, MidSample<L>* mid = nullptr,
                                    int* halves = nullptr) {
  switch (model) {
    case kSpring: return contact_finish<kSpring>(c, lf, in, zh, zdh, allow_cross, hold, b, cache, mid, halves);
    case kKelvinVoigt:
      return contact_finish<kKelvinVoigt>(c, lf, in, zh, zdh, allow_cross, hold, b, cache, mid, halves);
    case kHertz: return contact_finish<kHertz>(c, lf, in, zh, zdh, allow_cross, hold, b, cache, mid, halves);
    case kDmt: return contact_finish<kDmt>(c, lf, in, zh, zdh, allow_cross, hold, b, cache, mid, halves);
    case kDmtViscous:
      return contact_finish<kDmtViscous>(c, lf, in, zh, zdh, allow_cross, hold, b, cache, mid, halves);
    default: return true;
  }
}

// After a contact step: the smooth part of the tip from the state (base part plus mode 1), the
// look-ahead's threshold (a lane in contact needs the force whatever its path) and its bound.
template <int P, int L, int LD>
TIPFORCE_HD void after_contact_step(const StepConstants<P>& c, const StepInput<P, LD>& in, LaneBlock<P, L>& b) {
  for (int l = 0; l < L; ++l) {
    b.zs[l] = in.zb1[LD == 1 ? 0 : l] + c.phi[0] * b.q[0][l];
    b.zds[l] = in.zbd1[LD == 1 ? 0 : l] + c.phi[0] * b.v[0][l];
    b.gate[l] = b.in[l] ? -1e300 : b.contact_at[l];
  }
  update_reach(c, b);
}

// The contact levels of a coarse step: the level of a lane's contact substeps (-1: free flight
// over the step) from its state, the free update's end (zh, zdh; zs1, zds1 its smooth part) and
// its force law, and the level should the lane cross; the block runs at its stiffest lane's.
struct StepLevelsNeeded {
  int contact, crossing;
};

template <int P, int L>
TIPFORCE_HD StepLevelsNeeded block_level(const LaneBlock<P, L>& b, const LaneForce* lf, int model,
                                         const ContactResolution& res, double h, const double* zh, const double* zdh,
                                         const double* zs1, const double* zds1, const int* near) {
  const bool dmt = model == kDmt || model == kDmtViscous;
  StepLevelsNeeded top{0, 0};
  for (int l = 0; l < L; ++l) {
    int lev = -1, cross = -1;
    if (model == kSpring || model == kKelvinVoigt) {
      if (near[l]) {
        lev = b.linear_level[l];
        cross = b.linear_cross_level[l];
      }
    } else if (near[l] || dmt) {
      const double peak = smooth_peak(b.zs[l], b.zds[l], zs1[l], zds1[l], h) + b.reach[l];
      const double speed = fmax(fabs(b.zd[l]), fabs(zdh[l]));
      const double pen = fmax(peak, zh[l]) - lf[l].h + (dmt ? lf[l].a0 : 0.0);
      lev = hertzian_level(lf[l], model, pen, speed, h, res, res.rad_per_substep);
      cross = hertzian_level(lf[l], model, pen, speed, h, res, res.crossing_rad_per_substep);
    }
    top.contact = lev > top.contact ? lev : top.contact;
    top.crossing = cross > top.crossing ? cross : top.crossing;
  }
  if (top.crossing < top.contact) top.crossing = top.contact;
  return top;
}

// Takes count substeps of the crossing level (its constants c) from the drive's cursor, in place
// of a coarser substep in which a lane's branch changed (undone): each may locate a crossing.
template <int P, int L, class Source>
TIPFORCE_HD void refine_substep(const StepConstants<P>& c, int level, int count, int model, const LaneForce* lf, Source& src,
                                typename Source::Cursor& cursor, LaneBlock<P, L>& b, CollocationCache<L>& cache,
                                StepInput<P, Source::kLanes>& in) {
  constexpr int LD = Source::kLanes;
  double zh[L], zdh[L], zs1[L], zds1[L];
  src.set_substep_level(level);
  for (int r = 0; r < count; ++r) {
    src.template substep<P>(c, cursor, in);
    free_update<P, L, LD, Source::kHeld>(c, in, b, zh, zdh, zs1, zds1);
    contact_finish_any<P, L, LD>(model, c, lf, in, zh, zdh, true, HoldSolve::collocated, b, cache);
  }
}

// Advances every lane over coarse step j (from t_s, length levels[0].h_s). The drive source
// supplies each (sub)step's input: src.coarse(c, j, t_s, in) for the coarse step,
// src.substeps(j, t_s, level) a cursor over the 2^level substeps, src.substep(c, cursor, in) each.
// kMid: fill *mid with the tip and force at the step's midpoint (two samples per step); a template
// argument, so that a step per sample pays nothing for it.
template <int P, int L, class Source, bool kMid = false>
TIPFORCE_HD void advance_coarse_step(const StepConstants<P>* levels, int model, const LaneForce* lf,
                                     const ContactResolution& res, Source& src, int j, double t_s,
                                     LaneBlock<P, L>& b, CollocationCache<L>& cache, MidSample<L>* mid = nullptr) {
  constexpr int LD = Source::kLanes;
  constexpr bool kHeld = Source::kHeld;
  const StepConstants<P>& c0 = levels[0];
  const double h = c0.h_s;
  StepInput<P, LD> in;
  src.template coarse<P>(c0, j, t_s, in);
  double zh[L], zdh[L], zs1[L], zds1[L];
  free_update<P, L, LD, kHeld>(c0, in, b, zh, zdh, zs1, zds1);
  // A held drive's modal coordinates are the physical ones: the drive moves every mode, and a mode
  // it drives near resonance grows in free flight, which the reach at the step's start does not
  // bound (a chirp through the second mode's frequency went through its contacts unseen, 0.83 off
  // the reference). Over the step it takes the larger of its two ends'.
  double reach_end[kHeld ? L : 1];
  if constexpr (kHeld) {
    reach_of(c0, b, reach_end);
    for (int l = 0; l < L; ++l) b.reach[l] = b.reach[l] > reach_end[l] ? b.reach[l] : reach_end[l];
  }
  // Which lanes need the force over this step: a bound for all lanes at once (most steps are far
  // from the surface), the cubic through the smooth part's ends plus what the other modes add.
  double over[L];
  const double w = (4.0 / 27.0) * h;
TIPFORCE_IVDEP
  for (int l = 0; l < L; ++l) {
    const double zd0 = b.zds[l], zd1 = zds1[l], z0 = b.zs[l], z1 = zs1[l];
    const double up = zd0 > 0 ? zd0 : 0.0, down = zd1 < 0 ? -zd1 : 0.0;
    over[l] = (z0 > z1 ? z0 : z1) + w * (up + down) + b.reach[l] - b.gate[l];
  }
  double most = over[0];
  for (int l = 1; l < L; ++l) most = over[l] > most ? over[l] : most;
  int near[L];
  const int any_near = most > 0;
  if (any_near)
    for (int l = 0; l < L; ++l) near[l] = over[l] > 0;
  const bool dmt = model == kDmt || model == kDmtViscous;
  if (model == kNone || (!any_near && !dmt)) {
    // Free flight for every lane: the free update is the step.
TIPFORCE_IVDEP
    for (int l = 0; l < L; ++l) {
      b.z[l] = zh[l];
      b.zd[l] = zdh[l];
      b.zs[l] = zs1[l];
      b.zds[l] = zds1[l];
    }
    if constexpr (kHeld)
      for (int l = 0; l < L; ++l) b.reach[l] = reach_end[l];
    if constexpr (kMid) {
      free_tip_at<P, L, LD>(c0, in, b, 1, mid->z);
      for (int l = 0; l < L; ++l) mid->f[l] = b.f[l];
    }
    return;
  }
  if (dmt && !any_near) {
    // Every lane in the attraction's weak zone: level 0 (block_level's answer), the hold explicit.
    contact_finish_any<P, L, LD>(model, c0, lf, in, zh, zdh, true, HoldSolve::weak_attraction, b, cache,
                                 kMid ? mid : nullptr);
    after_contact_step(c0, in, b);
    return;
  }
  const StepLevelsNeeded need = block_level(b, lf, model, res, h, zh, zdh, zs1, zds1, near);
  // Level 0 finishes the free update; above it the step is undone and taken in 2^level substeps. A
  // (sub)step in which a lane's branch changes is undone and taken again in substeps of the crossing
  // level (the crossing is where the scheme's error comes from), unless it already was.
  const bool crossing_finer = need.crossing > need.contact;
  int crossing_halves = 3;
  if (need.contact == 0 && contact_finish_any<P, L, LD>(model, c0, lf, in, zh, zdh, !crossing_finer,
                                                        HoldSolve::collocated, b, cache, kMid ? mid : nullptr,
                                                        &crossing_halves)) {
    after_contact_step(c0, in, b);
    return;
  }
  undo_free_update<P, L, LD, kHeld>(c0, in, b);
  // The substeps: at the contact level, or after a refused coarse step, halves. A substep in which a
  // branch changes is taken in substeps of the crossing level (as a dyadic cell is exactly
  // 2^(crossing - level) of them), either because the refused step's collocated trajectory put a
  // crossing in it, or after it too is refused; the others keep their coarser level.
  const int level = need.contact == 0 ? 1 : need.contact;
  const bool hinted = need.contact == 0;
  const StepConstants<P>& c = levels[level];
  auto cursor = src.substeps(j, t_s, level);
  const int half = (1 << level) / 2;  // the midpoint is the end of the first half's last substep
  for (int s = 0; s < (1 << level); ++s) {
    const auto substep_start = cursor;
    bool refine = level < need.crossing && hinted && (crossing_halves >> s & 1);
    if (!refine) {
      src.template substep<P>(c, cursor, in);
      free_update<P, L, LD, kHeld>(c, in, b, zh, zdh, zs1, zds1);
      if (!contact_finish_any<P, L, LD>(model, c, lf, in, zh, zdh, level >= need.crossing, HoldSolve::collocated, b,
                                        cache)) {
        undo_free_update<P, L, LD, kHeld>(c, in, b);
        cursor = substep_start;
        refine = true;
      }
    }
    if (refine) {
      refine_substep(levels[need.crossing], need.crossing, 1 << (need.crossing - level), model, lf, src, cursor, b,
                     cache, in);
      src.set_substep_level(level);
    }
    if (kMid && s + 1 == half)
      for (int l = 0; l < L; ++l) {
        mid->z[l] = b.z[l];
        mid->f[l] = b.f[l];
      }
  }
  after_contact_step(c0, in, b);
}

// The block's tip, force and look-ahead state at the window's first instant from its modal state
// (q, v set by the caller, in the drive source's coordinates) and the drive's base part there.
template <int P, int L>
TIPFORCE_HD void start_block(const StepConstants<P>& c, const LaneForce* lf, const ContactResolution& res,
                             double coarse_h_s, const double* zb0, const double* zbd0, LaneBlock<P, L>& b) {
  for (int l = 0; l < L; ++l) {
    double u = 0, ud = 0;
    for (int i = 0; i < P; ++i) {
      u += c.phi[i] * b.q[i][l];
      ud += c.phi[i] * b.v[i][l];
    }
    b.z[l] = zb0[l] + u;
    b.zd[l] = zbd0[l] + ud;
    b.zs[l] = zb0[l] + c.phi[0] * b.q[0][l];
    b.zds[l] = zbd0[l] + c.phi[0] * b.v[0][l];
    b.in[l] = switching(lf[l], b.z[l], b.zd[l]) > 0 ? 1 : 0;
    b.f[l] = branch_force(lf[l], b.in[l] != 0, b.z[l], b.zd[l]);
    b.contact_at[l] = lf[l].h - refine_zone(lf[l], res);
    b.gate[l] = b.in[l] ? -1e300 : b.contact_at[l];
    const double c = lf[l].model == kKelvinVoigt ? lf[l].c : 0.0;
    b.linear_level[l] = level_for(lf[l].k, c, 0.0, coarse_h_s, res, res.rad_per_substep);
    const int cross = level_for(lf[l].k, c, 0.0, coarse_h_s, res, res.crossing_rad_per_substep);
    b.linear_cross_level[l] = cross > b.linear_level[l] ? cross : b.linear_level[l];
  }
  update_reach(c, b);
}

}  // namespace tipforce::detail
