#pragma once
// The body of one instruction set's block solve (cpu_step.hpp): included once by each unit, in an
// anonymous namespace, so that every unit keeps its own copy of everything it instantiates.
#include "cpu_step.hpp"

namespace tipforce::cpu {
namespace {

template <int P, int L>
struct BlockOutput {
  double cost[L];
  BlockJob* job;
  void sample(int n, const double* sig, const double* f, const double* z) {
    const BlockJob& j = *job;
    if (!j.traces) return;
    for (int l = 0; l < j.n_lanes; ++l) {
      if (j.signal[l]) j.signal[l][n] = sig[l];
      if (j.force[l]) j.force[l][n] = f[l];
      if (j.tip_z[l]) j.tip_z[l][n] = z[l];
    }
  }
};

template <int P, int L, class Source>
void solve_with(BlockJob& job, const detail::StepConstants<P>* levels, Source& src) {
  alignas(64) detail::LaneBlock<P, L> b;
  for (int i = 0; i < P; ++i)
    for (int l = 0; l < L; ++l) {
      b.q[i][l] = job.q[i][l];
      b.v[i][l] = job.v[i][l];
    }
  detail::WindowSetup<P> ws;
  ws.levels = levels;
  ws.resolution = job.resolution;
  ws.model = job.model;
  ws.n_samples = job.n_samples;
  ws.substeps = job.substeps;
  ws.samples_per_step = job.samples_per_step;
  ws.t0_s = job.t0_s;
  ws.displacement = job.displacement;
  ws.deflection = job.deflection;
  BlockOutput<P, L> o{{}, &job};
  detail::solve_window(ws, job.lanes, src, b, o);
  for (int l = 0; l < L; ++l) job.cost[l] = o.cost[l];
  for (int i = 0; i < P; ++i)
    for (int l = 0; l < L; ++l) {
      job.q[i][l] = b.q[i][l];
      job.v[i][l] = b.v[i][l];
    }
}

template <int P, int L>
void solve_padded(BlockJob& job, const detail::StepConstants<P>* levels) {
  if (job.held) {
    detail::SharedHeldSource src(*job.held);
    solve_with<P, L>(job, levels, src);
  } else if (job.sine) {
    detail::SharedSineSource src(*job.sine);
    solve_with<P, L>(job, levels, src);
  } else if (job.drive_kind == 0 /* DriveKind::sine */) {
    detail::PerLaneSineSource<L> src(levels[0], job.drive_params, job.t0_s, levels[0].h_s);
    solve_with<P, L>(job, levels, src);
  } else {
    detail::DriveFunction fn[L];
    for (int l = 0; l < L; ++l) {
      fn[l].kind = job.drive_kind;
      for (int k = 0; k < 4; ++k) fn[l].params[k] = job.drive_params[l][k];
      fn[l].t0_s = job.t0_s;
      fn[l].sample_period_s = levels[0].h_s * job.substeps;
    }
    detail::PerLaneHeldSource<L> src(fn, job.t0_s);
    solve_with<P, L>(job, levels, src);
  }
}

template <int L>
void solve_width(BlockJob& job) {
  if (job.levels8) solve_padded<8, L>(job, job.levels8);
  else solve_padded<32, L>(job, job.levels32);
}

// Lags in blocks of 32, each lag's sum its own accumulator, advanced as GCC vectors of 8 (one
// AVX-512 register, two AVX2 ones, four SSE2 ones): every sum in the order of the plain dot product.
// (Written as plain loops, GCC vectorised along the samples instead and spilled.)
typedef double LagVector __attribute__((vector_size(64)));
constexpr int kLagVector = 8, kLagVectors = 4, kLagBlock = kLagVector * kLagVectors;
void lag_products_here(const double* r, int n, int lags, double* out) {
  for (int k0 = 1; k0 <= lags; k0 += kLagBlock) {
    LagVector acc[kLagVectors] = {};
    const int body = n - (k0 + kLagBlock - 1);  // i < body: every lag of the block inside the window
    for (int i = 0; i < body; ++i) {
      const double ri = r[i];
      _Pragma("GCC unroll 4") for (int v = 0; v < kLagVectors; ++v) {
        LagVector x;
        __builtin_memcpy(&x, r + i + k0 + v * kLagVector, sizeof x);
        acc[v] += ri * x;
      }
    }
    const int in_block = lags - k0 + 1 < kLagBlock ? lags - k0 + 1 : kLagBlock;
    for (int j = 0; j < in_block; ++j) {
      double s = acc[j / kLagVector][j % kLagVector];
      for (int i = body > 0 ? body : 0; i + k0 + j < n; ++i) s += r[i] * r[i + k0 + j];
      out[k0 - 1 + j] = s;
    }
  }
}

void solve_block_here(BlockJob& job) {
  switch (job.width) {
    case 1: return solve_width<1>(job);
    case 2: return solve_width<2>(job);
    case 4: return solve_width<4>(job);
    default: return solve_width<kLanes>(job);
  }
}

}  // namespace
}  // namespace tipforce::cpu
