// The forward kernel: one thread per parameter set, the time loop inside. The per-step arithmetic
// is the CPU backend's, from one source (tipforce/detail/forward_step.hpp, one lane per thread).
#include <cstddef>

#include "forward_kernel.hpp"

namespace tipforce::cuda {
namespace {

using detail::LaneForce;

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

constexpr int kMaxBlock = 128;

// Parameter set s through the whole window: detail/forward_step.hpp's arithmetic with one lane,
// the modes padded to P (zero constants keep the padding at exactly zero).
template <int P, class Source>
__host__ __device__ __forceinline__ void solve_set(const ForwardLaunch& k, int s, const Source& src, double y0,
                                                   double yd0) {
  const int N = k.n_samples, K = k.substeps, S = k.n_sets;
  const auto* levels = static_cast<const detail::StepConstants<P>*>(k.d_levels);
  const LaneForce lf[1] = {k.d_lane[s]};
  detail::LaneBlock<P, 1> b;
  const int si = k.n_init == 1 ? 0 : s;
  for (int i = 0; i < P; ++i) {
    b.q[i][0] = ld(&k.d_initial[static_cast<std::size_t>(i) * k.n_init + si]);
    b.v[i][0] = ld(&k.d_initial[static_cast<std::size_t>(P + i) * k.n_init + si]);
  }
  detail::start_block(levels[0], P, lf, k.resolution, levels[0].h_s, &y0, &yd0, b);
  double sig;
  detail::measured_signal(levels[0], P, k.displacement, b, &sig);
  double cost = (ld(&k.d_deflection[0]) - sig) * (ld(&k.d_deflection[0]) - sig);
  const std::size_t row = static_cast<std::size_t>(s) * N;
  auto record = [&](int n) {
    if (k.want_signal) k.d_signal[row + n] = sig;
    if (k.want_force) {
      k.d_force[row + n] = b.f[0];
      k.d_tip_z[row + n] = b.z[0];
    }
  };
  record(0);
  const double h = levels[0].h_s;
  constexpr int LD = 1;
  for (int j = 0; j < N * K; ++j) {
    detail::advance_coarse_step<P, 1, LD>(levels, P, k.model, lf, k.resolution, src, j, k.t0_s + j * h, b);
    if ((j + 1) % K != 0 || (j + 1) / K >= N) continue;
    const int n = (j + 1) / K;
    detail::measured_signal(levels[0], P, k.displacement, b, &sig);
    const double r = ld(&k.d_deflection[n]) - sig;
    cost += r * r;
    record(n);
  }
  k.d_cost[s] = cost;
  if (k.want_end_state) {
    for (int i = 0; i < P; ++i) {
      k.d_end[static_cast<std::size_t>(i) * S + s] = b.q[i][0];
      k.d_end[static_cast<std::size_t>(P + i) * S + s] = b.v[i][0];
    }
  }
}

template <int P, bool kPerSetDrive>
__host__ __device__ __forceinline__ void solve_set_any_drive(const ForwardLaunch& k, int s) {
  if constexpr (kPerSetDrive) {
    detail::PerLaneDriveSource<1> src;
    src.fn[0] = k.drive;
    for (int j = 0; j < 4; ++j) src.fn[0].params[j] = ld(&k.d_drive_params[static_cast<std::size_t>(j) * k.n_sets + s]);
    const detail::Motion m = src.fn[0].at(k.t0_s);
    solve_set<P>(k, s, src, m.y, m.yd);
  } else {
    detail::SharedDriveSource src;
    src.y_m = k.d_y;
    src.yd_m = k.d_ydot;
    src.dq = k.d_dq;
    src.dv = k.d_dv;
    src.dq_stride = P;
    src.fn = k.drive;
    solve_set<P>(k, s, src, ld(&k.d_y[0]), ld(&k.d_ydot[0]));
  }
}

template <int P, bool kPerSetDrive>
__global__ void __launch_bounds__(kMaxBlock) forward_kernel(const ForwardLaunch k) {
  const int s = static_cast<int>(blockIdx.x) * static_cast<int>(blockDim.x) + static_cast<int>(threadIdx.x);
  if (s < k.n_sets) solve_set_any_drive<P, kPerSetDrive>(k, s);
}

// Sets are independent and each thread runs the whole window, so a small batch is best spread
// over as many multiprocessors as possible (warp-sized blocks); a large one uses fuller blocks.
int block_threads(int n_sets, int sm_count) {
  return n_sets <= 4 * 32 * (sm_count > 0 ? sm_count : 1) ? 32 : kMaxBlock;
}

template <int P>
cudaError_t launch_padded(const ForwardLaunch& a, cudaStream_t stream) {
  const int threads = block_threads(a.n_sets, a.sm_count);
  const int blocks = (a.n_sets + threads - 1) / threads;
  if (a.per_set_drive)
    forward_kernel<P, true><<<blocks, threads, 0, stream>>>(a);
  else
    forward_kernel<P, false><<<blocks, threads, 0, stream>>>(a);
  return cudaGetLastError();
}

template <int P>
cudaError_t run_padded_on_host(const ForwardLaunch& a, cudaStream_t) {
  for (int s = 0; s < a.n_sets; ++s) {
    if (a.per_set_drive)
      solve_set_any_drive<P, true>(a, s);
    else
      solve_set_any_drive<P, false>(a, s);
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
