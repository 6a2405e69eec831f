#pragma once
// A block of parameter sets through a whole window, for both backends (the CPU with 8 lanes, the
// CUDA kernel with one): the drive sources that feed forward_step.hpp's steps, and the window loop
// with its outputs behind a small policy. Only plain data and host/device functions.
//
// A sine drive is taken exactly: the modal coordinates are the deviation from the drive's free
// steady state (a closed form), which obeys the free equations plus the tip-sample force, so no
// drive term enters any step. A chirp or a sampled base enters through a quadratic hold of the
// base acceleration (held drives).
#include <cmath>

#include "tipforce/detail/forward_step.hpp"

namespace tipforce::detail {

// Rotation of a phasor (sin, cos) by omega h times each of the hold's points after the start (the
// inner points, then the end) for one substep level.
struct SineRotation {
  double c[kPoints - 1] = {1, 1, 1, 1}, s[kPoints - 1] = {0, 0, 0, 0};
};

TIPFORCE_HD void rotate(double s, double c, double cr, double sr, double& s_out, double& c_out) {
  s_out = s * cr + c * sr;
  c_out = c * cr - s * sr;
}

// A sine drive shared by every set, prepared on the host once per window (forward_setup.hpp):
// at each coarse step j (j <= steps) the phase's sine and cosine, the base y, and the tip's base
// part zb (base plus every mode's steady state) with its velocity; at each step's inner points the
// same (zbn[j * kInner + n]).
// The steady state of mode i is q = qr sin + qi cos, v = omega (qr cos - qi sin).
struct SharedSineView {
  const double* ph_s = nullptr;
  const double* ph_c = nullptr;
  const double* y = nullptr;
  const double* zb = nullptr;
  const double* zbd = nullptr;
  const double* zbn = nullptr;
  const double* zbdn = nullptr;
  const double* qr = nullptr;  // [i], padded modes
  const double* qi = nullptr;
  const double* ym = nullptr;  // [j]: the base at coarse step j's midpoint (two samples per step)
  double az = 0, bz = 0;       // zb = az sin + bz cos
  double ag = 0, bg = 0;       // the steady state's optical-lever signal, ag sin + bg cos
  double omega = 0;            // rad/s
  SineRotation rot[kSubstepLevels];
};

template <class T>
TIPFORCE_HD T load(const T* p) {
#ifdef __CUDA_ARCH__
  return __ldg(p);
#else
  return *p;
#endif
}

// The drive sources: what forward_step.hpp's advance_coarse_step asks of a drive, and what the
// window loop needs at the window's ends (to and from the solver's coordinates) and per sample.
class SharedSineSource {
 public:
  static constexpr int kLanes = 1;
  static constexpr bool kHeld = false;
  static constexpr bool kMidBase = true;
  struct Cursor {
    double s, c;
  };
  TIPFORCE_HD explicit SharedSineSource(const SharedSineView& v) : v_(v) {}

  template <int P>
  TIPFORCE_HD void coarse(const StepConstants<P>&, int j, double, StepInput<P, 1>& in) const {
    in.zb1[0] = load(v_.zb + j + 1);
    in.zbd1[0] = load(v_.zbd + j + 1);
    for (int n = 0; n < kInner; ++n) {
      in.zbn[n][0] = load(v_.zbn + static_cast<long>(j) * kInner + n);
      in.zbdn[n][0] = load(v_.zbdn + static_cast<long>(j) * kInner + n);
    }
  }
  TIPFORCE_HD Cursor substeps(int j, double, int level) const {
    level_ = level;
    return {load(v_.ph_s + j), load(v_.ph_c + j)};
  }
  // The next substeps' level, from the same cursor (a substep refined in place).
  TIPFORCE_HD void set_substep_level(int level) const { level_ = level; }
  template <int P>
  TIPFORCE_HD void substep(const StepConstants<P>&, Cursor& k, StepInput<P, 1>& in) const {
    const SineRotation& r = v_.rot[level_];
    for (int n = 0; n < kPoints - 1; ++n) {
      double sn, cn;
      rotate(k.s, k.c, r.c[n], r.s[n], sn, cn);
      const double z = v_.az * sn + v_.bz * cn, zd = v_.omega * (v_.az * cn - v_.bz * sn);
      if (n < kInner) {
        in.zbn[n][0] = z;
        in.zbdn[n][0] = zd;
      } else {
        in.zb1[0] = z;
        in.zbd1[0] = zd;
        k = {sn, cn};
      }
    }
  }
  TIPFORCE_HD double base(int j, int) const { return load(v_.y + j); }
  TIPFORCE_HD double base_mid(int j, int) const { return load(v_.ym + j); }
  TIPFORCE_HD double tip_base(int j, int) const { return load(v_.zb + j); }
  TIPFORCE_HD double tip_base_velocity(int j, int) const { return load(v_.zbd + j); }
  TIPFORCE_HD double optical_base(int j, int) const { return v_.ag * load(v_.ph_s + j) + v_.bg * load(v_.ph_c + j); }
  // The steady state of mode i at coarse step j: subtracted at the start, added back at the end.
  template <int P, int L>
  TIPFORCE_HD void shift(int j, double sign, LaneBlock<P, L>& b) const {
    const double s = load(v_.ph_s + j), c = load(v_.ph_c + j);
    for (int i = 0; i < P; ++i) {
      const double qr = load(v_.qr + i), qi = load(v_.qi + i);
      const double qp = qr * s + qi * c, vp = v_.omega * (qr * c - qi * s);
      for (int l = 0; l < L; ++l) {
        b.q[i][l] += sign * qp;
        b.v[i][l] += sign * vp;
      }
    }
  }

 private:
  SharedSineView v_;
  mutable int level_ = 0;
};

// A sine drive per set (its amplitude, frequency or phase among the unknowns): each lane's phase
// advances by rotation (its own omega h); the steady state per lane follows from the modes.
template <int L>
class PerLaneSineSource {
 public:
  static constexpr int kLanes = L;
  static constexpr bool kHeld = false;
  static constexpr bool kMidBase = false;  // one sample per step only
  struct Cursor {
    double s[L], c[L];
  };
  // params[l]: amplitude, frequency, phase (the chirp term is zero for a sine).
  template <int P>
  TIPFORCE_HD PerLaneSineSource(const StepConstants<P>& c0, const double (*params)[4], double t0_s, double coarse_h_s)
      : h_(coarse_h_s) {
    constexpr double two_pi = 2.0 * 3.14159265358979323846;
    for (int l = 0; l < L; ++l) {
      const double a = params[l][0], w = two_pi * params[l][1], th0 = w * t0_s + params[l][2];
      a_[l] = a;
      omega_[l] = w;
      s_[l] = sin(th0);
      c_[l] = cos(th0);
      // Mode i's steady state: q = Im(Q e^{i theta}), Q = gamma a w^2 / (omega_i^2 - w^2 + 2 i zeta omega_i w).
      double az = a, bz = 0, ag = 0, bg = 0;
      for (int i = 0; i < P; ++i) {
        const double re = c0.omega[i] * c0.omega[i] - w * w, im = 2.0 * c0.zeta[i] * c0.omega[i] * w;
        const double den = re * re + im * im;
        const double g = den > 0 ? c0.gamma[i] * a * w * w / den : 0.0;
        qr_[i][l] = g * re;
        qi_[i][l] = -g * im;
        az += c0.phi[i] * qr_[i][l];
        bz += c0.phi[i] * qi_[i][l];
        ag += c0.gain[i] * qr_[i][l];
        bg += c0.gain[i] * qi_[i][l];
      }
      az_[l] = az;
      bz_[l] = bz;
      ag_[l] = ag;
      bg_[l] = bg;
    }
    for (int k = 0; k < kSubstepLevels; ++k) have_rot_[k] = false;
    rotation(0);
  }

  template <int P>
  TIPFORCE_HD void coarse(const StepConstants<P>&, int, double, StepInput<P, L>& in) {
    const SineRotation* r = rot_[0];
    for (int l = 0; l < L; ++l) fill(in, l, r[l], s_[l], c_[l]);
  }
  // Substeps restart from the step's start (the coarse call already moved the phase to its end).
  TIPFORCE_HD Cursor substeps(int, double, int level) {
    set_substep_level(level);
    Cursor k;
    const SineRotation* r = rot_[0];
    for (int l = 0; l < L; ++l) rotate(s_[l], c_[l], r[l].c[kPoints - 2], -r[l].s[kPoints - 2], k.s[l], k.c[l]);
    return k;
  }
  TIPFORCE_HD void set_substep_level(int level) {
    level_ = level;
    rotation(level);
  }
  template <int P>
  TIPFORCE_HD void substep(const StepConstants<P>&, Cursor& k, StepInput<P, L>& in) const {
    const SineRotation* r = rot_[level_];
    for (int l = 0; l < L; ++l) fill(in, l, r[l], k.s[l], k.c[l]);
  }
  // Per-sample values read the current phase: the window loop asks right after coarse step j - 1.
  TIPFORCE_HD double base(int, int l) const { return a_[l] * s_[l]; }
  TIPFORCE_HD double tip_base(int, int l) const { return az_[l] * s_[l] + bz_[l] * c_[l]; }
  TIPFORCE_HD double tip_base_velocity(int, int l) const { return omega_[l] * (az_[l] * c_[l] - bz_[l] * s_[l]); }
  TIPFORCE_HD double optical_base(int, int l) const { return ag_[l] * s_[l] + bg_[l] * c_[l]; }
  template <int P, int L2>
  TIPFORCE_HD void shift(int, double sign, LaneBlock<P, L2>& b) const {
    for (int i = 0; i < P; ++i)
      for (int l = 0; l < L; ++l) {
        b.q[i][l] += sign * (qr_[i][l] * s_[l] + qi_[i][l] * c_[l]);
        b.v[i][l] += sign * omega_[l] * (qr_[i][l] * c_[l] - qi_[i][l] * s_[l]);
      }
  }

 private:
  // The step's points from the phasor at its start (s, c), which moves to the end.
  template <int P>
  TIPFORCE_HD void fill(StepInput<P, L>& in, int l, const SineRotation& r, double& s, double& c) const {
    for (int n = 0; n < kPoints - 1; ++n) {
      double sn, cn;
      rotate(s, c, r.c[n], r.s[n], sn, cn);
      const double z = az_[l] * sn + bz_[l] * cn, zd = omega_[l] * (az_[l] * cn - bz_[l] * sn);
      if (n < kInner) {
        in.zbn[n][l] = z;
        in.zbdn[n][l] = zd;
      } else {
        in.zb1[l] = z;
        in.zbd1[l] = zd;
        s = sn;
        c = cn;
      }
    }
  }
  TIPFORCE_HD void rotation(int level) {
    if (have_rot_[level]) return;
    const double hl = h_ / (1 << level);
    for (int l = 0; l < L; ++l)
      for (int n = 0; n < kPoints - 1; ++n) {
        rot_[level][l].c[n] = cos(omega_[l] * hold_node(n + 1) * hl);
        rot_[level][l].s[n] = sin(omega_[l] * hold_node(n + 1) * hl);
      }
    have_rot_[level] = true;
  }

  double h_;
  double a_[L], omega_[L], s_[L], c_[L], az_[L], bz_[L], ag_[L], bg_[L];
  double qr_[kMaxModes][L], qi_[kMaxModes][L];
  SineRotation rot_[kSubstepLevels][L];
  bool have_rot_[kSubstepLevels];
  int level_ = 0;
};

// A held drive shared by every set (chirp, sampled base), prepared on the host once per window:
// per coarse step j the base (position, velocity), the tip's base part at the step's inner points
// and each mode's increment over the step; substeps evaluate the drive function.
struct SharedHeldView {
  const double* y = nullptr;    // [j], j <= steps
  const double* yd = nullptr;
  const double* zbn = nullptr;  // [j * kInner + n], j < steps
  const double* zbdn = nullptr;
  const double* dq = nullptr;   // [j * P + i], padded modes
  const double* dv = nullptr;
  const double* ym = nullptr;   // [j]: the base at coarse step j's midpoint (two samples per step)
  DriveFunction fn;
};

class SharedHeldSource {
 public:
  static constexpr int kLanes = 1;
  static constexpr bool kHeld = true;
  static constexpr bool kMidBase = true;
  struct Cursor {
    double t;
  };
  TIPFORCE_HD explicit SharedHeldSource(const SharedHeldView& v) : v_(v) {}

  template <int P>
  TIPFORCE_HD void coarse(const StepConstants<P>&, int j, double, StepInput<P, 1>& in) const {
    in.zb1[0] = load(v_.y + j + 1);
    in.zbd1[0] = load(v_.yd + j + 1);
    for (int n = 0; n < kInner; ++n) {
      in.zbn[n][0] = load(v_.zbn + static_cast<long>(j) * kInner + n);
      in.zbdn[n][0] = load(v_.zbdn + static_cast<long>(j) * kInner + n);
    }
    const long row = static_cast<long>(j) * P;
    for (int i = 0; i < P; ++i) {
      in.dq[i][0] = load(v_.dq + row + i);
      in.dv[i][0] = load(v_.dv + row + i);
    }
  }
  TIPFORCE_HD Cursor substeps(int, double t_s, int) const { return {t_s}; }
  TIPFORCE_HD void set_substep_level(int) const {}  // a substep's length is its constants' h_s
  template <int P>
  TIPFORCE_HD void substep(const StepConstants<P>& c, Cursor& k, StepInput<P, 1>& in) const {
    held_drive_step(c, v_.fn, k.t, 0, in);
    k.t += c.h_s;
  }
  TIPFORCE_HD double base(int j, int) const { return load(v_.y + j); }
  TIPFORCE_HD double base_mid(int j, int) const { return load(v_.ym + j); }
  TIPFORCE_HD double tip_base(int j, int) const { return load(v_.y + j); }
  TIPFORCE_HD double tip_base_velocity(int j, int) const { return load(v_.yd + j); }
  TIPFORCE_HD double optical_base(int, int) const { return 0.0; }
  template <int P, int L>
  TIPFORCE_HD void shift(int, double, LaneBlock<P, L>&) const {}

 private:
  SharedHeldView v_;
};

// A chirp per set (drive parameters among the unknowns): every step evaluates each lane's drive.
template <int L>
class PerLaneHeldSource {
 public:
  static constexpr int kLanes = L;
  static constexpr bool kHeld = true;
  static constexpr bool kMidBase = false;  // one sample per step only
  struct Cursor {
    double t;
  };
  TIPFORCE_HD PerLaneHeldSource(const DriveFunction* fn, double t0_s) {
    for (int l = 0; l < L; ++l) {
      fn_[l] = fn[l];
      const Motion m = fn_[l].at(t0_s);
      y_[l] = m.y;
      yd_[l] = m.yd;
    }
  }
  template <int P>
  TIPFORCE_HD void coarse(const StepConstants<P>& c, int, double t_s, StepInput<P, L>& in) {
    for (int l = 0; l < L; ++l) {
      held_drive_step(c, fn_[l], t_s, l, in);
      y_[l] = in.zb1[l];
      yd_[l] = in.zbd1[l];
    }
  }
  TIPFORCE_HD Cursor substeps(int, double t_s, int) const { return {t_s}; }
  TIPFORCE_HD void set_substep_level(int) const {}  // a substep's length is its constants' h_s
  template <int P>
  TIPFORCE_HD void substep(const StepConstants<P>& c, Cursor& k, StepInput<P, L>& in) const {
    for (int l = 0; l < L; ++l) held_drive_step(c, fn_[l], k.t, l, in);
    k.t += c.h_s;
  }
  TIPFORCE_HD double base(int, int l) const { return y_[l]; }
  TIPFORCE_HD double tip_base(int, int l) const { return y_[l]; }
  TIPFORCE_HD double tip_base_velocity(int, int l) const { return yd_[l]; }
  TIPFORCE_HD double optical_base(int, int) const { return 0.0; }
  template <int P, int L2>
  TIPFORCE_HD void shift(int, double, LaneBlock<P, L2>&) const {}

 private:
  DriveFunction fn_[L];
  double y_[L], yd_[L];
};

// What one window solve needs besides the lanes and the drive.
template <int P>
struct WindowSetup {
  const StepConstants<P>* levels = nullptr;  // the coarse step and its refinements
  ContactResolution resolution;
  int model = 0;
  int n_samples = 0;
  int substeps = 1;  // coarse steps per sample
  // Or samples per coarse step: 2 where the sample period is short against every time scale of
  // the motion (samples_per_step), the odd samples at the steps' midpoints. Then substeps is 1,
  // the samples even in number, the sensor the displacement and the drive shared (kMidBase).
  int samples_per_step = 1;
  double t0_s = 0;
  bool displacement = true;
  const double* deflection = nullptr;  // measured signal, n_samples values
};

// A block through the window: b.q and b.v hold the initial modal state (physical); on return they
// hold the state one sample period after the last sample. out.sample(n, sig, f, z) is called at
// each sample with the simulated signal, the force and the tip; out.cost[l] receives the sum of
// squared residuals.
template <int P, int L, class Source, class Out>
TIPFORCE_HD void solve_window(const WindowSetup<P>& w, const LaneForce* lf, Source& src, LaneBlock<P, L>& b, Out& out) {
  const StepConstants<P>* levels = w.levels;
  const int N = w.n_samples, K = w.substeps;
  src.shift(0, -1.0, b);
  double zb0[L], zbd0[L];
  for (int l = 0; l < L; ++l) {
    zb0[l] = src.tip_base(0, l);
    zbd0[l] = src.tip_base_velocity(0, l);
  }
  start_block(levels[0], lf, w.resolution, levels[0].h_s, zb0, zbd0, b);
  double cost[L], sig[L];
  for (int l = 0; l < L; ++l) cost[l] = 0.0;
  // Sample n from the tip z and force f, the base (displacement sensor) y_of(l). The sensor's
  // choice outside the lane loops, so that they vectorise (one lane at a time, this was a tenth of
  // a 1 MHz solve).
  auto record = [&](int n, const double* z, const double* f, auto y_of, int j) {
    const double meas = load(w.deflection + n);
    // The residual in the signal's own lane loop: a loop of its own reloaded the signal in wider
    // vectors than it was stored in, which stalled on every sample.
    if (w.displacement) {
TIPFORCE_IVDEP
      for (int l = 0; l < L; ++l) {
        sig[l] = z[l] - y_of(l);
        const double r = meas - sig[l];
        cost[l] += r * r;
      }
    } else {
TIPFORCE_IVDEP
      for (int l = 0; l < L; ++l) {
        double s = src.optical_base(j, l);
        TIPFORCE_UNROLL_MODES
        for (int i = 0; i < P; ++i) s += levels[0].gain[i] * b.q[i][l];
        sig[l] = s;
        const double r = meas - s;
        cost[l] += r * r;
      }
    }
    out.sample(n, sig, f, z);
  };
  auto sample = [&](int n, int j) { record(n, b.z, b.f, [&](int l) { return src.base(j, l); }, j); };
  sample(0, 0);
  const double h = levels[0].h_s;
  CollocationCache<L> cache;
  // Two samples per step (only where the source has the base at the midpoints): the odd one at
  // each step's middle.
  const bool two = Source::kMidBase && w.samples_per_step == 2;
  MidSample<L> mid;
  const int steps = two ? N / 2 : N * K;
  for (int j = 0; j < steps; ++j) {
    if constexpr (Source::kMidBase) {
      if (two) {
        advance_coarse_step<P, L, Source, true>(levels, w.model, lf, w.resolution, src, j, w.t0_s + j * h, b, cache,
                                                &mid);
        record(2 * j + 1, mid.z, mid.f, [&](int l) { return src.base_mid(j, l); }, j);
        if (2 * j + 2 < N) sample(2 * j + 2, j + 1);
        continue;
      }
    }
    advance_coarse_step(levels, w.model, lf, w.resolution, src, j, w.t0_s + j * h, b, cache);
    if ((j + 1) % K == 0 && (j + 1) / K < N) sample((j + 1) / K, j + 1);
  }
  src.shift(steps, 1.0, b);
  for (int l = 0; l < L; ++l) out.cost[l] = cost[l];
}

}  // namespace tipforce::detail
