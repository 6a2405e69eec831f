// The CUDA backend against the CPU backend (the reference implementation of the scheme): same
// signals, forces, end states and costs to 1e-9 in double, for every force model, shared and
// per-set drives and initial states; the same inversions. Every test runs twice: on the GPU
// (skipping itself, saying why, where there is none) and with the kernel's per-set code run on
// the host ("host_emulation": everything but the device itself, checked on any machine).
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cmath>
#include <numbers>
#include <random>
#include <stdexcept>
#include <string>
#include <thread>

#include "test_support.hpp"
#include "tipforce/cuda_backend.hpp"
#include "tipforce/fallback_backend.hpp"
#include "host_emulation.hpp"  // cuda/src: the backend with its kernel run on the host

namespace tipforce {
namespace {
using testing::free_tip_amplitude;
using testing::full_params;
using testing::paper_probe;
using testing::sine_window;

enum class Engine { gpu, host_emulation };
const auto kEngines = ::testing::Values(Engine::gpu, Engine::host_emulation);
const char* engine_name(Engine e) { return e == Engine::gpu ? "gpu" : "host_emulation"; }
void PrintTo(Engine e, std::ostream* os) { *os << engine_name(e); }

std::unique_ptr<ForwardBackend> make_engine(Engine e, std::string* why_not) {
  return e == Engine::gpu ? make_cuda_backend_unwrapped(why_not) : cuda::make_host_emulation_backend();
}

// The bare CUDA backend (or its host emulation), or skip the test.
#define TIPFORCE_ENGINE_OR_SKIP(var, engine)                             \
  std::string var##_why_not;                                             \
  auto var = make_engine(engine, &var##_why_not);                        \
  if (!var) GTEST_SKIP() << "no CUDA device: " << var##_why_not
#define TIPFORCE_GPU_OR_SKIP(var) TIPFORCE_ENGINE_OR_SKIP(var, Engine::gpu)

constexpr double kTol = 1e-9;
// The force is the one output that follows a located crossing's last bits: where contact begins
// is a Newton root, and the CPU's AVX2/AVX-512 step (fused multiply-adds) and the emulation's
// baseline x86-64 build round its iterates differently. Signal and end state stay within kTol.
constexpr double kForceTol = 1e-8;

// Relative L2 difference; the absolute one where the reference is zero (e.g. no contact).
double rel_diff(const std::vector<double>& a, const std::vector<double>& ref) {
  double num = 0, den = 0;
  for (std::size_t i = 0; i < ref.size(); ++i) {
    num += (a[i] - ref[i]) * (a[i] - ref[i]);
    den += ref[i] * ref[i];
  }
  return den > 0 ? std::sqrt(num / den) : std::sqrt(num);
}

std::vector<double> flatten(const std::vector<ModalState>& states) {
  std::vector<double> v;
  for (const ModalState& s : states) {
    v.insert(v.end(), s.q.begin(), s.q.end());
    v.insert(v.end(), s.v.begin(), s.v.end());
  }
  return v;
}

// The CPU's answer for each set of the batch solved alone: a CPU block advances at its stiffest
// set's substep level, a GPU thread at its own set's (forward_step.hpp), so only a set solved alone
// on the CPU takes exactly the GPU's steps.
ForwardOutput cpu_sets_alone(const ForwardProblem& pb, const ForwardBatch& batch) {
  auto cpu = make_cpu_backend(1);
  const int S = batch.n_sets;
  const std::size_t nf = batch.params.size() / static_cast<std::size_t>(S);
  ForwardOutput all;
  for (int s = 0; s < S; ++s) {
    std::vector<double> p(nf);
    for (std::size_t k = 0; k < nf; ++k) p[k] = batch.params[k * static_cast<std::size_t>(S) + static_cast<std::size_t>(s)];
    ForwardBatch one = batch;
    one.n_sets = 1;
    one.params = p;
    one.initial = batch.initial.size() == 1 ? batch.initial : batch.initial.subspan(static_cast<std::size_t>(s), 1);
    ForwardOutput o;
    cpu->solve(pb, one, o);
    all.cost.push_back(o.cost[0]);
    all.signal.insert(all.signal.end(), o.signal.begin(), o.signal.end());
    all.force_n.insert(all.force_n.end(), o.force_n.begin(), o.force_n.end());
    all.tip_z_m.insert(all.tip_z_m.end(), o.tip_z_m.begin(), o.tip_z_m.end());
    all.end_state.insert(all.end_state.end(), o.end_state.begin(), o.end_state.end());
  }
  return all;
}

// Solves the batch on both backends and compares everything that was asked for.
void expect_same_as_cpu(ForwardBackend& gpu, const ForwardProblem& pb, const ForwardBatch& batch,
                        const std::string& what) {
  ForwardOutput got;
  const ForwardOutput want = cpu_sets_alone(pb, batch);
  gpu.solve(pb, batch, got);
  ASSERT_EQ(got.cost.size(), want.cost.size()) << what;
  for (std::size_t s = 0; s < want.cost.size(); ++s) {
    ASSERT_TRUE(std::isfinite(got.cost[s])) << what << " set " << s;
    EXPECT_NEAR(got.cost[s], want.cost[s], kTol * std::abs(want.cost[s]) + 1e-300) << what << " set " << s;
  }
  const std::size_t N = static_cast<std::size_t>(pb.window->n_samples());
  auto per_set = [&](const std::vector<double>& a, const std::vector<double>& b, const char* name, double tol = kTol) {
    ASSERT_EQ(a.size(), b.size()) << what << " " << name;
    EXPECT_LT(rel_diff(a, b), tol) << what << " " << name;
    for (std::size_t s = 0; s * N < b.size(); ++s) {
      const std::vector<double> as(a.begin() + s * N, a.begin() + (s + 1) * N), bs(b.begin() + s * N, b.begin() + (s + 1) * N);
      EXPECT_LT(rel_diff(as, bs), tol) << what << " " << name << " set " << s;
    }
  };
  if (batch.want_signal) per_set(got.signal, want.signal, "signal");
  if (batch.want_force) {
    per_set(got.force_n, want.force_n, "force", kForceTol);
    per_set(got.tip_z_m, want.tip_z_m, "tip z");
  }
  if (batch.want_end_state) {
    ASSERT_EQ(got.end_state.size(), want.end_state.size()) << what;
    for (const ModalState& e : got.end_state) ASSERT_EQ(e.q.size(), want.end_state[0].q.size()) << what;
    EXPECT_LT(rel_diff(flatten(got.end_state), flatten(want.end_state)), kTol) << what << " end state";
  }
}

// A batch in structure-of-arrays form built from full parameter vectors.
struct Batch {
  std::vector<double> soa;
  std::vector<ModalState> initial;
  ForwardBatch batch;
  Batch(const std::vector<std::vector<double>>& sets, std::vector<ModalState> init) : initial(std::move(init)) {
    const std::size_t S = sets.size(), P = sets[0].size();
    soa.resize(S * P);
    for (std::size_t s = 0; s < S; ++s)
      for (std::size_t k = 0; k < P; ++k) soa[k * S + s] = sets[s][k];
    batch.n_sets = static_cast<int>(S);
    batch.params = soa;
    batch.initial = initial;
    batch.want_signal = batch.want_force = batch.want_end_state = true;
  }
};

struct ModelCase {
  ForceModelKind model;
  std::vector<double> params;  // the model's parameters; entry h_index is set from the free amplitude
  int h_index;                 // -1: no surface
};

void PrintTo(const ModelCase& c, std::ostream* os) { *os << to_string(c.model); }

std::string case_name(const ::testing::TestParamInfo<std::tuple<ModelCase, Engine>>& info) {
  return std::string(to_string(std::get<0>(info.param).model)) + "_" + engine_name(std::get<1>(info.param));
}
std::string engine_case_name(const ::testing::TestParamInfo<Engine>& info) { return engine_name(info.param); }

const auto kEveryModel = ::testing::Values(
    ModelCase{ForceModelKind::none, {}, -1}, ModelCase{ForceModelKind::spring, {4.0, 0.0}, 1},
    ModelCase{ForceModelKind::kelvin_voigt, {4.0, 5e-6, 0.0}, 2}, ModelCase{ForceModelKind::hertz, {1e9, 10e-9, 0.0}, 2},
    ModelCase{ForceModelKind::dmt, {1e9, 10e-9, 1e-19, 0.3e-9, 0.0}, 4},
    ModelCase{ForceModelKind::dmt_viscous, {1e9, 10e-9, 1e-19, 0.3e-9, 0.0, 200.0}, 4});

// Model parameters of set s: the case's, stiffness-like entries and the surface varied per set
// (the surface stays inside the oscillation, so every set taps).
std::vector<double> model_params_of_set(const ModelCase& c, double amp, int s) {
  std::vector<double> p = c.params;
  if (!p.empty()) p[0] *= 1.0 + 0.05 * s;
  if (c.h_index >= 0) p[static_cast<std::size_t>(c.h_index)] = amp * (0.75 + 0.004 * s);
  return p;
}

int contact_samples(const ForwardOutput& out) {
  return static_cast<int>(std::count_if(out.force_n.begin(), out.force_n.end(), [](double f) { return f < 0; }));
}

class CudaForward : public ::testing::TestWithParam<std::tuple<ModelCase, Engine>> {};

TEST_P(CudaForward, SharedDriveAndInitialStateMatchCpu) {
  TIPFORCE_ENGINE_OR_SKIP(gpu, std::get<1>(GetParam()));
  const ModelCase c = std::get<0>(GetParam());
  const ModalModel modal(paper_probe());
  // 10 MHz and 1 MHz: at 1 MHz contact takes the substeps of forward_step.hpp.
  for (double dt : {1e-7, 1e-6}) {
    Window w = sine_window(2000, 2e-9, 25600.0, dt);
    for (int i = 0; i < w.n_samples(); ++i) w.deflection_m[i] = 1e-8 * std::sin(i * 0.013);
    const double amp = free_tip_amplitude(modal, 2e-9, 25600.0);
    const int K = default_substeps(c.model);
    const StepCoefficients step = make_step_coefficients(modal, w.sample_period_s / K);
    const ForwardProblem pb{&modal, &step, c.model, &w, K};
    std::vector<std::vector<double>> sets;
    for (int s = 0; s < 37; ++s) sets.push_back(full_params(model_params_of_set(c, amp, s), w));
    Batch b(sets, {linear_steady_state(modal, 2e-9, 25600.0, 0.0, 0.0)});
    const std::string what = std::string(to_string(c.model)) + " dt " + std::to_string(dt);
    expect_same_as_cpu(*gpu, pb, b.batch, what);
    if (c.h_index >= 0) {
      ForwardOutput out;
      gpu->solve(pb, b.batch, out);
      EXPECT_GT(contact_samples(out), 37 * 100) << "the case must have contact";
    }
    // Cost alone (the inversion's usual request).
    b.batch.want_signal = b.batch.want_force = b.batch.want_end_state = false;
    expect_same_as_cpu(*gpu, pb, b.batch, what + " cost only");
  }
}

TEST_P(CudaForward, PerSetDriveAndInitialStatesMatchCpu) {
  TIPFORCE_ENGINE_OR_SKIP(gpu, std::get<1>(GetParam()));
  const ModelCase c = std::get<0>(GetParam());
  const ModalModel modal(paper_probe());
  for (DriveKind kind : {DriveKind::sine, DriveKind::chirp}) {
    Window w = sine_window(2000, 2e-9, 25600.0, 1e-7, 3.7e-4);
    if (kind == DriveKind::chirp) {
      w.drive.kind = DriveKind::chirp;
      w.drive.chirp_hz_per_s = 2e6;
    }
    for (int i = 0; i < w.n_samples(); ++i) w.deflection_m[i] = 1e-8 * std::sin(i * 0.013);
    const double amp = free_tip_amplitude(modal, 2e-9, 25600.0);
    const int K = default_substeps(c.model);
    const StepCoefficients step = make_step_coefficients(modal, w.sample_period_s / K);
    const ForwardProblem pb{&modal, &step, c.model, &w, K};
    std::vector<std::vector<double>> sets;
    std::vector<ModalState> init;
    for (int s = 0; s < 45; ++s) {
      std::vector<double> p = full_params(model_params_of_set(c, amp, s), w);
      const std::size_t d = p.size() - kDriveParameterCount;
      p[d + 0] *= 1.0 + 0.01 * s;  // amplitude
      p[d + 1] += 15.0 * s;        // frequency
      p[d + 2] = 0.05 * s;         // phase
      if (kind == DriveKind::chirp) p[d + 3] *= 1.0 - 0.01 * s;
      sets.push_back(p);
      init.push_back(linear_steady_state(modal, 2e-9, 25600.0, 0.0, s * 1.3e-6));
    }
    Batch b(sets, init);
    b.batch.drive_varies = true;
    expect_same_as_cpu(*gpu, pb, b.batch, std::string(to_string(c.model)) + (kind == DriveKind::chirp ? " chirp" : " sine"));
  }
}

INSTANTIATE_TEST_SUITE_P(EveryForceModel, CudaForward, ::testing::Combine(kEveryModel, kEngines), case_name);

class CudaForwardCases : public ::testing::TestWithParam<Engine> {};
INSTANTIATE_TEST_SUITE_P(Engines, CudaForwardCases, kEngines, engine_case_name);

TEST_P(CudaForwardCases, SampledDriveMatchesCpu) {
  TIPFORCE_ENGINE_OR_SKIP(gpu, GetParam());
  const ModalModel modal(paper_probe());
  Window w = sine_window(1500);
  w.drive.kind = DriveKind::sampled;
  for (int i = 0; i < w.n_samples(); ++i) {
    w.drive.base_m.push_back(2e-9 * std::sin(2 * std::numbers::pi * 25600.0 * i * 1e-7) + 1e-10 * std::sin(i * 0.3));
    w.deflection_m[i] = 1e-8 * std::cos(i * 0.02);
  }
  const double amp = free_tip_amplitude(modal, 2e-9, 25600.0);
  for (int K : {1, 3}) {
    const StepCoefficients step = make_step_coefficients(modal, w.sample_period_s / K);
    const ForwardProblem pb{&modal, &step, ForceModelKind::spring, &w, K};
    std::vector<std::vector<double>> sets;
    for (int s = 0; s < 20; ++s) sets.push_back(full_params({4.0 + s, amp * (0.7 + 0.01 * s)}, w));
    Batch b(sets, {linear_steady_state(modal, 2e-9, 25600.0, 0.0, 0.0)});
    b.batch.drive_varies = true;  // ignored for a sampled drive, as on the CPU
    expect_same_as_cpu(*gpu, pb, b.batch, "sampled, substeps " + std::to_string(K));
  }
}

TEST_P(CudaForwardCases, AnyModeCountAndOpticalLeverMatchCpu) {
  TIPFORCE_ENGINE_OR_SKIP(gpu, GetParam());
  for (int modes : {1, 2, 3, 8, 13, 32}) {
    ProbeSpec spec = paper_probe(modes);
    spec.sensor = Sensor::optical_lever;
    spec.quality_factors = {100.0};
    const ModalModel modal(spec);
    Window w = sine_window(1200);
    for (int i = 0; i < w.n_samples(); ++i) w.deflection_m[i] = 5e-9 * std::sin(i * 0.016);
    const double amp = free_tip_amplitude(modal, 2e-9, 25600.0);
    const StepCoefficients step = make_step_coefficients(modal, w.sample_period_s);
    const ForwardProblem pb{&modal, &step, ForceModelKind::kelvin_voigt, &w, 1};
    std::vector<std::vector<double>> sets;
    for (int s = 0; s < 33; ++s) sets.push_back(full_params({3.0 + 0.1 * s, 4e-6, amp * (0.7 + 0.005 * s)}, w));
    Batch b(sets, {linear_steady_state(modal, 2e-9, 25600.0, 0.0, 0.0)});
    expect_same_as_cpu(*gpu, pb, b.batch, std::to_string(modes) + " modes");
    b.batch.drive_varies = true;
    expect_same_as_cpu(*gpu, pb, b.batch, std::to_string(modes) + " modes, per-set drive");
  }
}

TEST_P(CudaForwardCases, LargeBatchMatchesCpu) {
  TIPFORCE_ENGINE_OR_SKIP(gpu, GetParam());
  const ModalModel modal(paper_probe());
  Window w = sine_window(300);
  for (int i = 0; i < w.n_samples(); ++i) w.deflection_m[i] = 1e-8 * std::sin(i * 0.02);
  const StepCoefficients step = make_step_coefficients(modal, w.sample_period_s);
  const ForwardProblem pb{&modal, &step, ForceModelKind::spring, &w, 1};
  std::vector<std::vector<double>> sets;
  for (int s = 0; s < 40001; ++s) sets.push_back(full_params({0.5 + 1e-4 * s, 1e-9 + 1e-13 * s}, w));
  Batch b(sets, {ModalState::rest(8)});
  b.batch.want_force = false;
  expect_same_as_cpu(*gpu, pb, b.batch, "40001 sets");
}

// The workspace caches the window's samples and the shared drive across calls: changes in place
// (same Window object, same addresses) must be seen, and smaller batches after larger ones work.
TEST_P(CudaForwardCases, WorkspaceReuseSeesEveryChange) {
  TIPFORCE_ENGINE_OR_SKIP(gpu, GetParam());
  const ModalModel modal(paper_probe());
  Window w = sine_window(1000);
  const double amp = free_tip_amplitude(modal, 2e-9, 25600.0);
  for (int round = 0; round < 4; ++round) {
    for (int i = 0; i < w.n_samples(); ++i) w.deflection_m[i] = 1e-8 * std::sin(i * 0.01 * (round + 1));
    w.drive.amplitude_m = 2e-9 * (1.0 + 0.1 * round);
    w.t0_s = round * 1e-4;
    const int K = 1 + round % 2;
    const StepCoefficients step = make_step_coefficients(modal, w.sample_period_s / K);
    const ForwardProblem pb{&modal, &step, ForceModelKind::spring, &w, K};
    std::vector<std::vector<double>> sets;
    for (int s = 0; s < (round % 2 ? 3 : 70); ++s) sets.push_back(full_params({4.0 + s, amp * 0.8}, w));
    Batch b(sets, {linear_steady_state(modal, 2e-9, 25600.0, 0.0, round * 1e-4)});
    b.batch.want_force = round % 2 == 0;
    expect_same_as_cpu(*gpu, pb, b.batch, "round " + std::to_string(round));
  }
  // A window that grows, then shrinks.
  for (int n : {5000, 10, 1}) {
    Window v = sine_window(n);
    for (int i = 0; i < n; ++i) v.deflection_m[i] = 1e-9 * i;
    const StepCoefficients step = make_step_coefficients(modal, v.sample_period_s);
    const ForwardProblem pb{&modal, &step, ForceModelKind::spring, &v, 1};
    Batch b({full_params({4.0, amp * 0.8}, v), full_params({5.0, amp * 0.7}, v)},
            {linear_steady_state(modal, 2e-9, 25600.0, 0.0, 0.0)});
    expect_same_as_cpu(*gpu, pb, b.batch, std::to_string(n) + " samples");
  }
}

// Several backends (one stream each) solving at once, as several probes do.
TEST(CudaConcurrency, ConcurrentBackendsMatchCpu) {
  TIPFORCE_GPU_OR_SKIP(first);
  auto second = make_cuda_backend_unwrapped();
  ASSERT_TRUE(second);
  const ModalModel modal(paper_probe());
  const double amp = free_tip_amplitude(modal, 2e-9, 25600.0);
  auto work = [&](ForwardBackend& gpu, ForceModelKind model, std::vector<double> p, ForwardOutput& got,
                  ForwardOutput& want) {
    Window w = sine_window(3000);
    for (int i = 0; i < w.n_samples(); ++i) w.deflection_m[i] = 1e-8 * std::sin(i * 0.01);
    const int K = default_substeps(model);
    const StepCoefficients step = make_step_coefficients(modal, w.sample_period_s / K);
    const ForwardProblem pb{&modal, &step, model, &w, K};
    std::vector<std::vector<double>> sets;
    for (int s = 0; s < 64; ++s) sets.push_back(full_params(p, w));
    Batch b(sets, {linear_steady_state(modal, 2e-9, 25600.0, 0.0, 0.0)});
    for (int rep = 0; rep < 10; ++rep) gpu.solve(pb, b.batch, got);
    make_cpu_backend(1)->solve(pb, b.batch, want);
  };
  ForwardOutput g1, w1, g2, w2;
  std::thread t1([&] { work(*first, ForceModelKind::spring, {4.0, 0.8 * amp}, g1, w1); });
  std::thread t2([&] { work(*second, ForceModelKind::hertz, {1e9, 10e-9, 0.8 * amp}, g2, w2); });
  t1.join();
  t2.join();
  EXPECT_LT(rel_diff(g1.signal, w1.signal), kTol);
  EXPECT_LT(rel_diff(g2.signal, w2.signal), kTol);
  EXPECT_LT(rel_diff(g1.force_n, w1.force_n), kForceTol);
  EXPECT_LT(rel_diff(g2.force_n, w2.force_n), kForceTol);
}

TEST_P(CudaForwardCases, MalformedBatchIsRefusedLikeOnTheCpu) {
  TIPFORCE_ENGINE_OR_SKIP(gpu, GetParam());
  const ModalModel modal(paper_probe());
  Window w = sine_window(100);
  const StepCoefficients step = make_step_coefficients(modal, w.sample_period_s);
  const ForwardProblem pb{&modal, &step, ForceModelKind::spring, &w, 1};
  Batch b({full_params({4.0, 5e-9}, w)}, {ModalState::rest(8)});
  std::vector<double> short_params(5, 0.0);
  b.batch.params = short_params;
  ForwardOutput out;
  EXPECT_THROW(gpu->solve(pb, b.batch, out), std::invalid_argument);
  b.batch.params = b.soa;
  const ModalState wrong = ModalState::rest(3);
  b.batch.initial = std::span<const ModalState>(&wrong, 1);
  EXPECT_THROW(gpu->solve(pb, b.batch, out), std::invalid_argument);
  // Still usable afterwards.
  b.batch.initial = b.initial;
  expect_same_as_cpu(*gpu, pb, b.batch, "after refusals");
}

// ---- the inversion on the GPU --------------------------------------------------------------------

struct InversionPair {
  Estimate cpu, gpu;
};

void expect_same_estimate(const InversionPair& e, const char* what) {
  ASSERT_EQ(e.cpu.values.size(), 2u) << what << e.cpu.message;
  ASSERT_EQ(e.gpu.values.size(), 2u) << what << e.gpu.message;
  EXPECT_EQ(e.gpu.status, e.cpu.status) << what << " " << e.gpu.message;
  EXPECT_NE(e.gpu.status, EstimateStatus::rejected) << what << " " << e.gpu.message;
  for (std::size_t j = 0; j < 2; ++j) {
    EXPECT_GT(e.cpu.sigma[j], 0.0) << what;
    EXPECT_NEAR(e.gpu.values[j], e.cpu.values[j], e.cpu.sigma[j])
        << what << " " << e.cpu.names[j] << " gpu sigma " << e.gpu.sigma[j];
    EXPECT_NEAR(e.gpu.sigma[j], e.cpu.sigma[j], 0.1 * e.cpu.sigma[j]) << what << " " << e.cpu.names[j];
  }
  EXPECT_NEAR(e.gpu.misfit, e.cpu.misfit, 1e-3 * e.cpu.misfit + 1e-12) << what;
  EXPECT_NEAR(e.gpu.peak_force_n, e.cpu.peak_force_n, 1e-3 * e.cpu.peak_force_n) << what;
}

class CudaInversion : public ::testing::TestWithParam<Engine> {};
INSTANTIATE_TEST_SUITE_P(Engines, CudaInversion, kEngines, engine_case_name);

TEST_P(CudaInversion, SpringEstimateAndWarmStartMatchCpu) {
  TIPFORCE_ENGINE_OR_SKIP(gpu, GetParam());
  const ModalModel modal(paper_probe());
  ParameterSpace space(ForceModelKind::spring);
  space.make_unknown("k_n_per_m", 0.1, 20.0);
  space.make_unknown("h_m", 20e-9, 80e-9);
  auto cpu = make_cpu_backend(0);
  Inverter on_cpu(ProbeModel{"p", modal, space, {}}, *cpu);
  Inverter on_gpu(ProbeModel{"p", modal, space, {}}, *gpu);
  std::mt19937_64 rng(11);
  std::normal_distribution<double> noise(0.0, 0.2e-9);

  // Window 1 from rest, window 2 directly after it (INITIAL_CONTINUED: the warm start and the
  // fitted end state carry over).
  ModalState truth_state = ModalState::rest(8);
  for (int px = 0; px < 2; ++px) {
    Window w = sine_window(4000, 2e-9, 25600.0, 1e-7, px * 4000 * 1e-7);
    const ReferenceResult truth =
        reference_simulate(modal, ForceModelKind::spring, w, full_params({4.0, 50e-9}, w), truth_state);
    truth_state = truth.end_state;
    for (int i = 0; i < w.n_samples(); ++i) w.deflection_m[i] = truth.signal[i] + noise(rng);
    w.initial = px == 0 ? InitialState::rest : InitialState::continued;
    if (px == 1) {
      ASSERT_TRUE(on_cpu.has_warm_start());
      ASSERT_TRUE(on_gpu.has_warm_start());
    }
    const InversionPair e{on_cpu.invert(w), on_gpu.invert(w)};
    const std::string what = "window " + std::to_string(px);
    if (std::getenv("TIPFORCE_TEST_VERBOSE"))
      std::printf("%s: cpu k %.6f +- %.2e h %.6e +- %.2e (%d solves) | %s k %.6f +- %.2e h %.6e +- %.2e (%d solves) %s\n",
                  what.c_str(), e.cpu.values[0], e.cpu.sigma[0], e.cpu.values[1], e.cpu.sigma[1], e.cpu.forward_solves,
                  engine_name(GetParam()), e.gpu.values[0], e.gpu.sigma[0], e.gpu.values[1], e.gpu.sigma[1],
                  e.gpu.forward_solves, e.gpu.message.c_str());
    expect_same_estimate(e, what.c_str());
    // And both found the truth.
    EXPECT_NEAR(e.gpu.values[0], 4.0, std::max(0.01 * 4.0, 3 * e.gpu.sigma[0])) << what;
    EXPECT_NEAR(e.gpu.values[1], 50e-9, std::max(0.01 * 50e-9, 3 * e.gpu.sigma[1])) << what;
  }
}

// ---- construction --------------------------------------------------------------------------------

TEST(CudaBackendFactory, MakesAFallbackWrappedBackendOrSaysWhyNot) {
  std::string why_not;
  const int devices = cuda_device_count(&why_not);
  auto backend = make_cuda_backend(&why_not);
  if (devices == 0) {
    EXPECT_EQ(backend, nullptr);
    EXPECT_FALSE(why_not.empty());
    GTEST_SKIP() << "no CUDA device: " << why_not << " (make_cuda_backend returned nullptr, as it must)";
  }
  ASSERT_NE(backend, nullptr) << why_not;
  EXPECT_EQ(backend->description().rfind("cuda: ", 0), 0u) << backend->description();
  auto* fallback = dynamic_cast<FallbackBackend*>(backend.get());
  ASSERT_NE(fallback, nullptr);
  const ModalModel modal(paper_probe());
  Window w = sine_window(500);
  const StepCoefficients step = make_step_coefficients(modal, w.sample_period_s);
  const ForwardProblem pb{&modal, &step, ForceModelKind::spring, &w, 1};
  Batch b({full_params({4.0, 5e-9}, w)}, {ModalState::rest(8)});
  expect_same_as_cpu(*backend, pb, b.batch, "wrapped");
  EXPECT_EQ(fallback->fallbacks(), 0u) << fallback->last_error();
}

TEST(CudaBackendFactory, UnwrappedBackendDescribesItsDevice) {
  TIPFORCE_GPU_OR_SKIP(gpu);
  EXPECT_EQ(gpu->description().rfind("cuda: ", 0), 0u) << gpu->description();
  EXPECT_GT(gpu->description().size(), 6u);
  std::string why;
  EXPECT_EQ(make_cuda_backend_unwrapped(&why, 1000), nullptr);
  EXPECT_NE(why.find("not present"), std::string::npos) << why;
}

}  // namespace
}  // namespace tipforce
