#pragma once
// The CPU backend's block solve (and the HAC's lag products), compiled once per instruction set
// (cpu_step_baseline.cpp, cpu_step_x86_64_v3.cpp, cpu_step_x86_64_v4.cpp: the same code under other
// -march flags) and chosen at run time (cpu_backend.cpp). Plain data in and out: a unit built for
// AVX-512 must instantiate nothing the others share (a standard-library template emitted there
// could be the copy the linker keeps for every unit, and an AVX2 machine would then die on it).
#include "tipforce/detail/forward_step.hpp"
#include "tipforce/detail/forward_window.hpp"

namespace tipforce::cpu {

// Sets advanced together: a block is 1, 2, 4 or 8 lanes wide (8: one AVX-512 vector). A narrow
// block costs less per set when a batch has few sets (the lanes of a wide block are computed
// whether they hold a set or a padding copy), and a batch of a few sets split into narrow
// blocks keeps both cores busy. Measured at 1 MHz (spring, one thread): one set 95 us in a block
// of 1 against 193 in one of 8; three sets 224 us in blocks of 2 against 291 in one of 8; 256 sets
// 30 us per set in blocks of 8 against 38 in blocks of 4.
inline constexpr int kLanes = 8;  // the widest block
inline constexpr int kWidths[] = {1, 2, 4, 8};

// One block of up to `width` sets through one window.
struct BlockJob {
  int width = kLanes;  // one of kWidths: the lanes computed (the arrays below use the first width)
  // The problem.
  int model = 0;
  int n_samples = 0;
  int substeps = 1;
  int samples_per_step = 1;  // detail::WindowSetup::samples_per_step
  double t0_s = 0;
  bool displacement = true;
  const double* deflection = nullptr;
  detail::ContactResolution resolution;
  // Step levels for the padded mode count: up to 8 modes run as 8, more as 32.
  const detail::StepConstants<8>* levels8 = nullptr;
  const detail::StepConstants<32>* levels32 = nullptr;
  // The drive: shared by the batch (one of the views), else per lane (kind, parameters).
  const detail::SharedSineView* sine = nullptr;
  const detail::SharedHeldView* held = nullptr;
  int drive_kind = 0;
  double drive_params[kLanes][4] = {};
  // The lanes (a block of fewer sets than its width repeats its last one) and their initial state.
  detail::LaneForce lanes[kLanes];
  double q[detail::kMaxModes][kLanes] = {}, v[detail::kMaxModes][kLanes] = {};
  // Outputs: the traces (lane l < n_lanes writes n_samples values from signal[l] etc.; null when
  // not wanted: a block's sets need not be neighbours in the batch), the cost, and in q and v the
  // state one sample period after the last sample.
  int n_lanes = kLanes;
  bool traces = false;  // any of the below wanted
  double* signal[kLanes] = {};
  double* force[kLanes] = {};
  double* tip_z[kLanes] = {};
  double cost[kLanes] = {};
};

enum class Isa { baseline, x86_64_v3, x86_64_v4 };

void solve_block_baseline(BlockJob& job);
#if defined(TIPFORCE_CPU_CLONES)
void solve_block_x86_64_v3(BlockJob& job);
void solve_block_x86_64_v4(BlockJob& job);
#endif

// The residual's lag products out[k - 1] = sum over i + k < n of r[i] r[i + k], k = 1 .. lags (the
// HAC inflation's autocorrelations, covariance.cpp): a warm 1 MHz window's 200 lags of 1250
// samples took 37-42 us as one dot product per lag in the baseline build (6 % of the window), 12 us
// in the AVX-512 build of this.
void lag_products_baseline(const double* r, int n, int lags, double* out);
#if defined(TIPFORCE_CPU_CLONES)
void lag_products_x86_64_v3(const double* r, int n, int lags, double* out);
void lag_products_x86_64_v4(const double* r, int n, int lags, double* out);
#endif
// The build for the best instruction set this CPU has (best: true), or the baseline's.
void lag_products(const double* r, int n, int lags, double* out, bool best = true);

}  // namespace tipforce::cpu
