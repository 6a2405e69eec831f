// The forward kernel: one thread per parameter set, the time loop inside. The window loop and the
// per-step arithmetic are the CPU backend's, from one source (tipforce/detail/forward_window.hpp and
// forward_step.hpp, one lane per thread).
#include <cstddef>

#include "forward_kernel.hpp"

namespace tipforce::cuda {
namespace {

using detail::LaneForce;
using detail::load;

constexpr int kMaxBlock = 128;

// The window loop's outputs for one set.
template <int P>
struct SetOutput {
  double cost[1];
  const ForwardLaunch* k;
  std::size_t row;
  __host__ __device__ __forceinline__ void sample(int n, const double* sig, const double* f, const double* z) {
    if (k->want_signal) k->d_signal[row + n] = sig[0];
    if (k->want_force) {
      k->d_force[row + n] = f[0];
      k->d_tip_z[row + n] = z[0];
    }
  }
};

// Parameter set s through the whole window, the modes padded to P (zero constants keep the
// padding at exactly zero).
template <int P, class Source>
__host__ __device__ __forceinline__ void solve_set(const ForwardLaunch& k, int s, Source& src) {
  const int S = k.n_sets;
  const LaneForce lf[1] = {k.d_lane[s]};
  detail::LaneBlock<P, 1> b;
  const int si = k.n_init == 1 ? 0 : s;
  for (int i = 0; i < P; ++i) {
    b.q[i][0] = load(&k.d_initial[static_cast<std::size_t>(i) * k.n_init + si]);
    b.v[i][0] = load(&k.d_initial[static_cast<std::size_t>(P + i) * k.n_init + si]);
  }
  detail::WindowSetup<P> ws;
  ws.levels = static_cast<const detail::StepConstants<P>*>(k.d_levels);
  ws.resolution = k.resolution;
  ws.model = k.model;
  ws.n_samples = k.n_samples;
  ws.substeps = k.substeps;
  ws.samples_per_step = k.samples_per_step;
  ws.t0_s = k.t0_s;
  ws.displacement = k.displacement;
  ws.deflection = k.d_deflection;
  SetOutput<P> o{{0.0}, &k, static_cast<std::size_t>(s) * k.n_samples};
  detail::solve_window(ws, lf, src, b, o);
  k.d_cost[s] = o.cost[0];
  if (k.want_end_state) {
    for (int i = 0; i < P; ++i) {
      k.d_end[static_cast<std::size_t>(i) * S + s] = b.q[i][0];
      k.d_end[static_cast<std::size_t>(P + i) * S + s] = b.v[i][0];
    }
  }
}

template <int P>
__host__ __device__ __forceinline__ void solve_set_any_drive(const ForwardLaunch& k, int s) {
  if (!k.per_set_drive) {
    if (k.held_drive) {
      detail::SharedHeldSource src(k.held);
      solve_set<P>(k, s, src);
    } else {
      detail::SharedSineSource src(k.sine);
      solve_set<P>(k, s, src);
    }
    return;
  }
  double dp[1][4];
  for (int j = 0; j < 4; ++j) dp[0][j] = load(&k.d_drive_params[static_cast<std::size_t>(j) * k.n_sets + s]);
  const auto* levels = static_cast<const detail::StepConstants<P>*>(k.d_levels);
  if (!k.held_drive) {
    detail::PerLaneSineSource<1> src(levels[0], dp, k.t0_s, k.sample_period_s / k.substeps);
    solve_set<P>(k, s, src);
  } else {
    detail::DriveFunction fn[1];
    fn[0].kind = k.drive_kind;
    for (int j = 0; j < 4; ++j) fn[0].params[j] = dp[0][j];
    fn[0].t0_s = k.t0_s;
    fn[0].sample_period_s = k.sample_period_s;
    detail::PerLaneHeldSource<1> src(fn, k.t0_s);
    solve_set<P>(k, s, src);
  }
}

template <int P>
__global__ void __launch_bounds__(kMaxBlock) forward_kernel(const ForwardLaunch k) {
  const int s = static_cast<int>(blockIdx.x) * static_cast<int>(blockDim.x) + static_cast<int>(threadIdx.x);
  if (s < k.n_sets) solve_set_any_drive<P>(k, s);
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
  forward_kernel<P><<<blocks, threads, 0, stream>>>(a);
  return cudaGetLastError();
}

template <int P>
cudaError_t run_padded_on_host(const ForwardLaunch& a, cudaStream_t) {
  for (int s = 0; s < a.n_sets; ++s) solve_set_any_drive<P>(a, s);
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
  return cudaFuncGetAttributes(&attr, forward_kernel<8>);
}

}  // namespace tipforce::cuda
