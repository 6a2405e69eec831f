// The forward kernel: one thread per parameter set, the time loop inside, the same per-step
// arithmetic as the CPU backend (lib/src/cpu_backend.cpp) and the shared per-set contact step
// (tipforce/detail/contact_step.hpp).
#include <cstddef>

#include "forward_kernel.hpp"

namespace tipforce::cuda {
namespace {

using detail::ContactResult;
using detail::LaneForce;

// Per-mode constants for P (padded) modes; passed by value as a kernel parameter, so they sit in
// the constant bank and every read is a broadcast (and several backends never share them).
template <int P>
struct KernelParams {
  double a00[P], a01[P], a10[P], a11[P];
  double cs_q[P], cs_v[P], ce_q[P], ce_v[P];
  double phi[P], gain[P], gamma[P];
  double wq0[P], wv0[P], wqm[P], wvm[P], wq1[P], wv1[P];
  detail::TipStepResponse tip;
  int n_sets, n_samples, substeps, n_init, drive_kind;
  bool contact, want_signal, want_force, want_end_state;
  double t0_s, dt_s;
  const LaneForce* __restrict__ d_lane;
  const double* __restrict__ d_drive_params;
  const double* __restrict__ d_initial;
  const double* __restrict__ d_deflection;
  const double* __restrict__ d_y;
  const double* __restrict__ d_ydot;
  const double2* __restrict__ d_dqdv;
  double* __restrict__ d_cost;
  double* __restrict__ d_signal;
  double* __restrict__ d_force;
  double* __restrict__ d_tip_z;
  double* __restrict__ d_end;
};

// Loops over modes are unrolled on the device, so that a set's modes stay in registers (the
// host build of the same code, a check, goes without).
#ifdef __CUDA_ARCH__
#define TIPFORCE_UNROLL _Pragma("unroll")
#else
#define TIPFORCE_UNROLL
#endif

// Read-only global load through the non-coherent cache on the device; a plain load on the host
// (the host build runs the same per-set code to check it without a GPU).
template <class T>
__host__ __device__ __forceinline__ T ld(const T* p) {
#ifdef __CUDA_ARCH__
  return __ldg(p);
#else
  return *p;
#endif
}

struct Motion {
  double y, yd, ydd;
};

// base_motion of lib/src/drive.cpp (sine and chirp), on the device.
__host__ __device__ __forceinline__ Motion base_motion_d(int kind, double a, double f, double phase, double g, double t) {
  constexpr double two_pi = 2.0 * 3.14159265358979323846;
  double s, c;
  if (kind == 1 /* DriveKind::chirp */) {
    const double th = two_pi * (f + g * t) * t + phase;
    const double thd = two_pi * (f + 2.0 * g * t);
    const double thdd = 2.0 * two_pi * g;
    sincos(th, &s, &c);
    return {a * s, a * c * thd, a * (c * thdd - s * thd * thd)};
  }
  const double w = two_pi * f;
  const double th = w * t + phase;
  sincos(th, &s, &c);
  return {a * s, a * w * c, -a * w * w * s};
}

constexpr int kMaxBlock = 128;

// Everything one thread does: parameter set s through the whole window.
template <int P, bool kPerSetDrive>
__host__ __device__ __forceinline__ void solve_set(const KernelParams<P>& k, int s) {
  const int N = k.n_samples, K = k.substeps, S = k.n_sets;
  const LaneForce lf = k.d_lane[s];

  double q[P], v[P];
  {
    const int si = k.n_init == 1 ? 0 : s;
TIPFORCE_UNROLL
    for (int i = 0; i < P; ++i) {
      q[i] = ld(&k.d_initial[static_cast<std::size_t>(i) * k.n_init + si]);
      v[i] = ld(&k.d_initial[static_cast<std::size_t>(P + i) * k.n_init + si]);
    }
  }
  double dp[4] = {0, 0, 0, 0};
  double y0, yd0, acc0 = 0;
  if constexpr (kPerSetDrive) {
TIPFORCE_UNROLL
    for (int j = 0; j < 4; ++j) dp[j] = ld(&k.d_drive_params[static_cast<std::size_t>(j) * S + s]);
    const Motion b = base_motion_d(k.drive_kind, dp[0], dp[1], dp[2], dp[3], k.t0_s);
    y0 = b.y;
    yd0 = b.yd;
    acc0 = b.ydd;
  } else {
    y0 = ld(&k.d_y[0]);
    yd0 = ld(&k.d_ydot[0]);
  }
  double u = 0, ud = 0, sig = 0;
TIPFORCE_UNROLL
  for (int i = 0; i < P; ++i) {
    u += k.phi[i] * q[i];
    ud += k.phi[i] * v[i];
    sig += k.gain[i] * q[i];
  }
  double z = y0 + u, zd = yd0 + ud;
  bool in = detail::switching(lf, z, zd) > 0;
  double f = detail::branch_force(lf, in, z, zd);
  double cost;
  {
    const double r = ld(&k.d_deflection[0]) - sig;
    cost = r * r;
  }
  const std::size_t row = static_cast<std::size_t>(s) * N;
  if (k.want_signal) k.d_signal[row] = sig;
  if (k.want_force) {
    k.d_force[row] = f;
    k.d_tip_z[row] = z;
  }

  std::size_t step = 0;  // solver step index: n * K + substep
  for (int n = 0; n < N; ++n) {
    for (int sub = 0; sub < K; ++sub, ++step) {
      double dq[P], dv[P];
      double y1, yd1;
      if constexpr (kPerSetDrive) {
        const double t = k.t0_s + static_cast<double>(step) * k.dt_s;
        const double am = base_motion_d(k.drive_kind, dp[0], dp[1], dp[2], dp[3], t + 0.5 * k.dt_s).ydd;
        const Motion b1 = base_motion_d(k.drive_kind, dp[0], dp[1], dp[2], dp[3], t + k.dt_s);
TIPFORCE_UNROLL
        for (int i = 0; i < P; ++i) {
          dq[i] = -k.gamma[i] * (k.wq0[i] * acc0 + k.wqm[i] * am + k.wq1[i] * b1.ydd);
          dv[i] = -k.gamma[i] * (k.wv0[i] * acc0 + k.wvm[i] * am + k.wv1[i] * b1.ydd);
        }
        acc0 = b1.ydd;
        y1 = b1.y;
        yd1 = b1.yd;
      } else {
        y1 = ld(&k.d_y[step + 1]);
        yd1 = ld(&k.d_ydot[step + 1]);
        const double2* inc = k.d_dqdv + step * P;
TIPFORCE_UNROLL
        for (int i = 0; i < P; ++i) {
          const double2 d = ld(&inc[i]);
          dq[i] = d.x;
          dv[i] = d.y;
        }
      }
      // Exact linear update with the force held at its step-start value.
      double zh = y1, zdh = yd1;
TIPFORCE_UNROLL
      for (int i = 0; i < P; ++i) {
        const double qn = k.a00[i] * q[i] + k.a01[i] * v[i] + k.cs_q[i] * f + dq[i];
        const double vn = k.a10[i] * q[i] + k.a11[i] * v[i] + k.cs_v[i] * f + dv[i];
        q[i] = qn;
        v[i] = vn;
        zh += k.phi[i] * qn;
        zdh += k.phi[i] * vn;
      }
      if (k.contact) {
        // Step-end force, solved implicitly; then the hold's correction to every mode.
        const ContactResult r = detail::contact_step(lf, k.tip, zh, zdh, z, zd, f, in);
        f = r.f;
        in = r.in;
        z = zh + k.tip.z_end * r.alpha + k.tip.z_start * r.beta;
        zd = zdh + k.tip.v_end * r.alpha + k.tip.v_start * r.beta;
TIPFORCE_UNROLL
        for (int i = 0; i < P; ++i) {
          q[i] += k.ce_q[i] * r.alpha + k.cs_q[i] * r.beta;
          v[i] += k.ce_v[i] * r.alpha + k.cs_v[i] * r.beta;
        }
      } else {
        z = zh;
        zd = zdh;
      }
    }
    const int sample = n + 1;
    if (sample < N) {
      double sg = 0;
TIPFORCE_UNROLL
      for (int i = 0; i < P; ++i) sg += k.gain[i] * q[i];
      const double r = ld(&k.d_deflection[sample]) - sg;
      cost += r * r;
      if (k.want_signal) k.d_signal[row + sample] = sg;
      if (k.want_force) {
        k.d_force[row + sample] = f;
        k.d_tip_z[row + sample] = z;
      }
    }
  }
  k.d_cost[s] = cost;
  if (k.want_end_state) {
TIPFORCE_UNROLL
    for (int i = 0; i < P; ++i) {
      k.d_end[static_cast<std::size_t>(i) * S + s] = q[i];
      k.d_end[static_cast<std::size_t>(P + i) * S + s] = v[i];
    }
  }
}

template <int P, bool kPerSetDrive>
__global__ void __launch_bounds__(kMaxBlock) forward_kernel(const KernelParams<P> k) {
  const int s = static_cast<int>(blockIdx.x) * static_cast<int>(blockDim.x) + static_cast<int>(threadIdx.x);
  if (s < k.n_sets) solve_set<P, kPerSetDrive>(k, s);
}

template <int P>
KernelParams<P> kernel_params(const ForwardLaunch& a) {
  KernelParams<P> k{};
  const ModeConstants& m = a.modes;
  for (int i = 0; i < P; ++i) {
    k.a00[i] = m.a00[i];
    k.a01[i] = m.a01[i];
    k.a10[i] = m.a10[i];
    k.a11[i] = m.a11[i];
    k.cs_q[i] = m.cs_q[i];
    k.cs_v[i] = m.cs_v[i];
    k.ce_q[i] = m.ce_q[i];
    k.ce_v[i] = m.ce_v[i];
    k.phi[i] = m.phi[i];
    k.gain[i] = m.gain[i];
    k.gamma[i] = m.gamma[i];
    k.wq0[i] = m.wq0[i];
    k.wv0[i] = m.wv0[i];
    k.wqm[i] = m.wqm[i];
    k.wvm[i] = m.wvm[i];
    k.wq1[i] = m.wq1[i];
    k.wv1[i] = m.wv1[i];
  }
  k.tip = a.tip;
  k.n_sets = a.n_sets;
  k.n_samples = a.n_samples;
  k.substeps = a.substeps;
  k.n_init = a.n_init;
  k.drive_kind = a.drive_kind;
  k.contact = a.contact;
  k.want_signal = a.want_signal;
  k.want_force = a.want_force;
  k.want_end_state = a.want_end_state;
  k.t0_s = a.t0_s;
  k.dt_s = a.dt_s;
  k.d_lane = a.d_lane;
  k.d_drive_params = a.d_drive_params;
  k.d_initial = a.d_initial;
  k.d_deflection = a.d_deflection;
  k.d_y = a.d_y;
  k.d_ydot = a.d_ydot;
  k.d_dqdv = reinterpret_cast<const double2*>(a.d_dqdv);
  k.d_cost = a.d_cost;
  k.d_signal = a.d_signal;
  k.d_force = a.d_force;
  k.d_tip_z = a.d_tip_z;
  k.d_end = a.d_end;
  return k;
}

// Sets are independent and each thread runs the whole window, so a small batch is best spread
// over as many multiprocessors as possible (warp-sized blocks); a large one uses fuller blocks.
int block_threads(int n_sets, int sm_count) {
  return n_sets <= 4 * 32 * (sm_count > 0 ? sm_count : 1) ? 32 : kMaxBlock;
}

template <int P>
cudaError_t launch_padded(const ForwardLaunch& a, cudaStream_t stream) {
  const KernelParams<P> k = kernel_params<P>(a);
  const int threads = block_threads(a.n_sets, a.sm_count);
  const int blocks = (a.n_sets + threads - 1) / threads;
  if (a.per_set_drive)
    forward_kernel<P, true><<<blocks, threads, 0, stream>>>(k);
  else
    forward_kernel<P, false><<<blocks, threads, 0, stream>>>(k);
  return cudaGetLastError();
}

template <int P>
cudaError_t run_padded_on_host(const ForwardLaunch& a, cudaStream_t) {
  const KernelParams<P> k = kernel_params<P>(a);
  for (int s = 0; s < a.n_sets; ++s) {
    if (a.per_set_drive)
      solve_set<P, true>(k, s);
    else
      solve_set<P, false>(k, s);
  }
  return cudaSuccess;
}

template <template <int> class Run>
cudaError_t dispatch(const ForwardLaunch& a, cudaStream_t stream) {
  if (a.n_sets <= 0 || a.n_samples <= 0 || a.n_modes < 1 || a.n_modes > kMaxModes || a.substeps < 1)
    return cudaErrorInvalidValue;
  switch (padded_modes(a.n_modes)) {
    case 1: return Run<1>::run(a, stream);
    case 2: return Run<2>::run(a, stream);
    case 4: return Run<4>::run(a, stream);
    case 8: return Run<8>::run(a, stream);
    case 16: return Run<16>::run(a, stream);
    default: return Run<32>::run(a, stream);
  }
}
template <int P>
struct OnDevice {
  static cudaError_t run(const ForwardLaunch& a, cudaStream_t stream) { return launch_padded<P>(a, stream); }
};
template <int P>
struct OnHost {
  static cudaError_t run(const ForwardLaunch& a, cudaStream_t stream) { return run_padded_on_host<P>(a, stream); }
};

}  // namespace

cudaError_t launch_forward(const ForwardLaunch& a, cudaStream_t stream) { return dispatch<OnDevice>(a, stream); }

cudaError_t run_forward_on_host(const ForwardLaunch& a) { return dispatch<OnHost>(a, nullptr); }

cudaError_t forward_kernel_available() {
  cudaFuncAttributes attr{};
  return cudaFuncGetAttributes(&attr, forward_kernel<8, false>);
}

}  // namespace tipforce::cuda
