#pragma once
// The per-parameter-set part of one time step: solving the step-end tip-sample force implicitly and,
// across contact onset or release, the moment-matched hold (see lib/src/DESIGN.md). Plain functions
// on plain data so that the CPU backend and the CUDA kernels run the same arithmetic.
#include <cmath>

#if defined(__CUDACC__)
#define TIPFORCE_HD __host__ __device__ __forceinline__
// Never inlined on the device either: inlined into every call site, padded mode count and drive
// source, nvcc took over 15 minutes (cicc 10, ptxas 5) for the forward kernel on 2 cores; called,
// under 2 (cicc 18 s, ptxas 64 s). What the calls cost on the GPU is not yet measured.
#define TIPFORCE_HD_OUTLINE __host__ __device__ inline __noinline__
#else
// Inlined into every caller: the CPU step is compiled once per instruction set (cpu_backend.cpp).
#define TIPFORCE_HD [[gnu::always_inline]] inline
// The large pieces of a contact step stay functions of their own (inlined at every call they would
// multiply the compile time), with internal linkage: each instruction set's translation unit
// keeps its own copy, so that the linker cannot hand one unit's AVX-512 code to another.
#define TIPFORCE_HD_OUTLINE static inline
#endif

namespace tipforce::detail {

// Model codes: the values of ForceModelKind.
enum : int { kNone = 0, kSpring = 1, kKelvinVoigt = 2, kHertz = 3, kDmt = 4, kDmtViscous = 5 };

// One set's force-law constants, derived once per set.
struct LaneForce {
  int model = kNone;
  double k = 0;           // N/m
  double c = 0;           // N s/m
  double h = 0;           // m
  double big_k = 0;       // (4/3) E* sqrt(R)
  double hr6 = 0;         // H R / 6
  double a0 = 0;          // m
  double eta_sqrt_r = 0;  // eta sqrt(R)
  double f0 = 0;          // H R / (6 a0^2): DMT force at contact
};

// The tip's response at the step end (position, velocity) to a unit force held as (1 - s/dt)
// ("start") or s/dt ("end"): sums over modes of phi_i(L)^2 / (mu L) times the hold responses.
struct TipStepResponse {
  double z_start = 0, z_end = 0, v_start = 0, v_end = 0;
};

struct ContactResult {
  double f;      // force at the step end
  double alpha;  // end value of the equivalent linear hold
  double beta;   // start value of the equivalent hold minus the force at the step start
  bool in;       // contact branch at the step end
};

// > 0 in contact. Kelvin-Voigt is in contact while the tip is inside the sample and the clipped
// force is still repulsive.
TIPFORCE_HD double switching(const LaneForce& p, double z, double zd) {
  const double delta = z - p.h;
  switch (p.model) {
    case kSpring:
    case kHertz: return delta;
    case kKelvinVoigt: return fmin(p.k * delta, p.k * delta + p.c * zd);
    case kDmt:
    case kDmtViscous: return delta + p.a0;
    default: return -1.0;
  }
}

TIPFORCE_HD double branch_force(const LaneForce& p, bool in, double z, double zd) {
  const double delta = z - p.h;
  if (!in) {
    if (p.model == kDmt || p.model == kDmtViscous) {
      const double d = fmax(p.h - z, p.a0);
      return p.hr6 / (d * d);
    }
    return 0.0;
  }
  switch (p.model) {
    case kSpring: return -p.k * delta;
    case kKelvinVoigt: return fmin(0.0, -p.k * delta - p.c * zd);
    case kHertz: {
      const double d = fmax(delta, 0.0);
      return -p.big_k * d * sqrt(d);
    }
    case kDmt:
    case kDmtViscous: {
      const double pen = fmax(delta + p.a0, 0.0);
      double f = p.f0 - p.big_k * pen * sqrt(pen);
      if (p.model == kDmtViscous) f -= p.eta_sqrt_r * sqrt(pen) * zd;
      return f;
    }
    default: return 0.0;
  }
}

// Solves f = F_branch(zA + zB f, vA + vB f) for the step-end force (zB, vB >= 0 by construction).
TIPFORCE_HD double solve_branch(const LaneForce& p, bool in, double zA, double zB, double vA, double vB) {
  if (!in) {
    if (p.model != kDmt && p.model != kDmtViscous) return 0.0;
    // Weak, smooth attraction: two fixed-point sweeps are exact to rounding.
    double f = branch_force(p, false, zA, vA);
    f = branch_force(p, false, zA + zB * f, vA + vB * f);
    return branch_force(p, false, zA + zB * f, vA + vB * f);
  }
  switch (p.model) {
    case kSpring: return -p.k * (zA - p.h) / (1.0 + p.k * zB);
    case kKelvinVoigt: return fmin(0.0, (-p.k * (zA - p.h) - p.c * vA) / (1.0 + p.k * zB + p.c * vB));
    case kHertz:
    case kDmt: {
      // r(f) = f - f0 + K pen(f)^1.5 is increasing and convex: Newton from f0 (where r >= 0)
      // converges monotonically from the right.
      const double f0 = p.model == kDmt ? p.f0 : 0.0;
      const double shift = p.model == kDmt ? p.a0 : 0.0;
      double f = f0;
      for (int it = 0; it < 30; ++it) {
        const double pen = fmax(zA + zB * f - p.h + shift, 0.0);
        const double sq = sqrt(pen);
        const double r = f - f0 + p.big_k * pen * sq;
        const double dr = 1.0 + 1.5 * p.big_k * sq * zB;
        const double step = r / dr;
        f -= step;
        if (fabs(step) <= 1e-13 * fabs(f) + 1e-300) break;
      }
      return f;
    }
    case kDmtViscous: {
      double f = p.f0;
      for (int it = 0; it < 30; ++it) {
        const double pen = fmax(zA + zB * f - p.h + p.a0, 0.0);
        const double sq = sqrt(pen);
        const double zd = vA + vB * f;
        const double r = f - p.f0 + p.big_k * pen * sq + p.eta_sqrt_r * sq * zd;
        const double dsq = sq > 0 ? 0.5 / sq : 0.0;
        const double dr = 1.0 + 1.5 * p.big_k * sq * zB + p.eta_sqrt_r * (dsq * zB * zd + sq * vB);
        const double step = r / (dr > 0.1 ? dr : 0.1);
        f -= step;
        if (fabs(step) <= 1e-13 * fabs(f) + 1e-300) break;
      }
      return f;
    }
    default: return 0.0;
  }
}

// One step's force. zhat/zdhat: tip position/velocity at the step end with the force held at f_n;
// z_n/zd_n/f_n/in_n: at the step start.
TIPFORCE_HD ContactResult contact_step(const LaneForce& p, const TipStepResponse& r, double zhat, double zdhat,
                                       double z_n, double zd_n, double f_n, bool in_n) {
  if (p.model == kNone) return {0.0, 0.0, 0.0, false};
  // Regular step: the force stays on its branch and varies linearly over the step.
  const double f1 = solve_branch(p, in_n, zhat, r.z_end, zdhat, r.v_end);
  const double z1 = zhat + r.z_end * f1, zd1 = zdhat + r.v_end * f1;
  const double s1 = switching(p, z1, zd1);
  const bool in1 = s1 > 0;
  if (in1 == in_n) return {f1, f1, 0.0, in_n};

  // The branch changes inside the step. Up to the crossing the old branch governs the motion, so
  // its trajectory locates the crossing; the switching function is interpolated linearly.
  const double s0 = switching(p, z_n, zd_n);
  double theta = s0 / (s0 - s1);
  theta = theta < 0 ? 0 : (theta > 1 ? 1 : theta);
  const double zc = z_n + theta * (z1 - z_n), zdc = zd_n + theta * (zd1 - zd_n);
  const double fb = branch_force(p, in_n, zc, zdc);  // just before the crossing
  const double fa = branch_force(p, in1, zc, zdc);   // just after (differs for Kelvin-Voigt's damper)
  // Piecewise-linear force (f_n -> fb on [0, theta], fa -> f on [theta, 1]) replaced by the linear
  // hold (a, b) with the same zeroth and first moments; a and b are affine in the unknown f.
  const double om = 1.0 - theta;
  const double m0c = 0.5 * theta * (f_n + fb) + 0.5 * om * fa, m0f = 0.5 * om;
  const double m1c = theta * theta * (f_n + 2.0 * fb) / 6.0 + om * fa * (2.0 * theta + 1.0) / 6.0;
  const double m1f = om * (theta + 2.0) / 6.0;
  const double ac = 4.0 * m0c - 6.0 * m1c, af = 4.0 * m0f - 6.0 * m1f;
  const double bc = 6.0 * m1c - 2.0 * m0c, bf = 6.0 * m1f - 2.0 * m0f;
  const double zA = zhat + r.z_start * (ac - f_n) + r.z_end * bc, zB = r.z_start * af + r.z_end * bf;
  const double vA = zdhat + r.v_start * (ac - f_n) + r.v_end * bc, vB = r.v_start * af + r.v_end * bf;
  const double f = solve_branch(p, in1, zA, zB, vA, vB);
  return {f, bc + bf * f, ac + af * f - f_n, in1};
}

}  // namespace tipforce::detail
