#pragma once
// Host API of the forward kernel (plain C++; the kernel itself is in forward_kernel.cu).
//
// One thread per parameter set, running the CPU backend's window loop with one lane
// (tipforce/detail/forward_window.hpp). The modes of a set live in registers, padded to a
// compile-time count (1, 2, 4, 8, 16 or 32) with zero coefficients, which leave the padded
// coordinates at zero and add exact zeros to every sum, so the arithmetic of the real modes is the
// CPU backend's. Device arrays prepared by the host (d_ prefix) use the padded mode count
// P = padded_modes(M):
//   d_lane[s]                       per-set force constants
//   d_drive_params[k * S + s]       per-set drive (amplitude, frequency, phase, chirp), k < 4
//   d_initial[i * n_init + s']      q of mode i (i < P), then v at [(P + i) * n_init + s'];
//                                   s' = s for per-set initial states (n_init = S), else 0
//   d_deflection[n]                 measured signal, n < N
//   d_levels[j]                     detail::StepConstants<P> of the coarse step (j = 0) and its
//                                   refinements into 2^j substeps (j < kSubstepLevels)
//   sine / held                     the shared drive's views (detail::SharedSineView or
//                                   SharedHeldView), their arrays in device memory
// Outputs: d_cost[s]; d_signal / d_force / d_tip_z [s * N + n] (when wanted);
//          d_end[i * S + s] = q, d_end[(P + i) * S + s] = v (when wanted, i < P).
#include <cuda_runtime_api.h>

#include "tipforce/detail/contact_step.hpp"
#include "tipforce/detail/forward_setup.hpp"
#include "tipforce/detail/forward_step.hpp"
#include "tipforce/detail/forward_window.hpp"

namespace tipforce::cuda {

inline constexpr int kMaxModes = detail::kMaxModes;
using detail::padded_modes;

struct ForwardLaunch {
  int n_sets = 0;
  int n_samples = 0;
  int substeps = 1;
  int samples_per_step = 1;  // detail::WindowSetup::samples_per_step (the levels' step is that many samples)
  int n_modes = 0;          // real modes; the kernel runs padded_modes(n_modes)
  int n_init = 1;           // 1 (shared initial state) or n_sets
  bool per_set_drive = false;
  bool held_drive = false;  // chirp or sampled base (else sine)
  int drive_kind = 0;       // DriveKind value
  int model = 0;            // ForceModelKind value
  bool want_signal = false, want_force = false, want_end_state = false;
  int sm_count = 1;         // multiprocessors of the device (for the block size)
  bool displacement = true;  // sensor
  double t0_s = 0;
  double sample_period_s = 0;
  detail::ContactResolution resolution;
  detail::SharedSineView sine;  // the shared drive (device pointers), when !per_set_drive
  detail::SharedHeldView held;

  const void* d_levels = nullptr;  // detail::StepConstants<padded_modes(n_modes)>[kSubstepLevels]
  const detail::LaneForce* d_lane = nullptr;
  const double* d_drive_params = nullptr;
  const double* d_initial = nullptr;
  const double* d_deflection = nullptr;

  double* d_cost = nullptr;
  double* d_signal = nullptr;
  double* d_force = nullptr;
  double* d_tip_z = nullptr;
  double* d_end = nullptr;
};

// Queues the forward kernel on the stream; returns the launch error (cudaSuccess when queued).
[[nodiscard]] cudaError_t launch_forward(const ForwardLaunch& launch, cudaStream_t stream);

// The same per-set code, run on the host over every set with host pointers in place of the
// device ones (tests and debugging without a GPU). Synchronous.
[[nodiscard]] cudaError_t run_forward_on_host(const ForwardLaunch& launch);

// Whether the kernels have an image for the current device (cudaErrorNoKernelImageForDevice
// otherwise, e.g. a GPU older than the architectures this was built for).
[[nodiscard]] cudaError_t forward_kernel_available();

}  // namespace tipforce::cuda
