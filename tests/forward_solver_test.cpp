#include <gtest/gtest.h>

#include <cmath>
#include <complex>
#include <numbers>

#include "test_support.hpp"

namespace tipforce {
namespace {
using testing::free_tip_amplitude;
using testing::full_params;
using testing::paper_probe;
using testing::relative_l2;
using testing::sine_window;

TEST(ForwardSolver, LinearSineResponseStaysOnClosedFormSteadyStatePerMode) {
  const ModalModel modal(paper_probe());
  auto backend = make_cpu_backend(1);
  for (double f : {25600.0, 150000.0}) {
    Window w = sine_window(3000, 2e-9, f);
    const ModalState start = linear_steady_state(modal, 2e-9, f, 0.0, 0.0);
    const ForwardOutput out = simulate_one(*backend, modal, ForceModelKind::none, w, full_params({}, w), start);
    const double t_end = w.n_samples() * w.sample_period_s;
    const ModalState expect = linear_steady_state(modal, 2e-9, f, 0.0, t_end);
    const double omega = 2 * std::numbers::pi * f;
    for (int i = 0; i < modal.n_modes(); ++i) {
      // Amplitude and phase of mode i from (q, v / omega) as a phasor.
      const std::complex<double> got(out.end_state[0].q[i], out.end_state[0].v[i] / omega);
      const std::complex<double> want(expect.q[i], expect.v[i] / omega);
      EXPECT_LT(std::abs(got - want) / std::abs(want), 1e-4) << "mode " << i << " at " << f << " Hz";
      EXPECT_NEAR(std::abs(got) / std::abs(want), 1.0, 1e-4);
      EXPECT_NEAR(std::arg(got / want), 0.0, 1e-4);
    }
  }
}

struct ModelCase {
  ForceModelKind model;
  std::vector<double> params;  // model parameters; h_m is set from the free amplitude
  int h_index;
};

class AgainstReference : public ::testing::TestWithParam<ModelCase> {};

// Starting on the free steady state with the surface inside the oscillation, every cycle taps
// firmly (no grazing impacts, whose square-root sensitivity would amplify rounding).
TEST_P(AgainstReference, ForwardSolverMatchesAdaptiveReferenceWithContact) {
  const ModelCase c = GetParam();
  const ModalModel modal(paper_probe());
  auto backend = make_cpu_backend(2);
  Window w = sine_window(2500);
  const double amp = free_tip_amplitude(modal, 2e-9, 25600.0);
  std::vector<double> p = c.params;
  p[static_cast<std::size_t>(c.h_index)] = 0.8 * amp;
  const ModalState start = linear_steady_state(modal, 2e-9, 25600.0, 0.0, 0.0);
  const auto full = full_params(p, w);
  const ReferenceResult ref = reference_simulate(modal, c.model, w, full, start);
  const ForwardOutput fast = simulate_one(*backend, modal, c.model, w, full, start);
  int contact = 0;
  for (double f : ref.force_n) contact += f < 0;
  EXPECT_GT(contact, 100) << "the case must have contact";
  const double err = relative_l2(fast.signal, ref.signal);
  EXPECT_LT(err, 1e-4) << to_string(c.model);
  // The force itself, where it matters (the contact samples).
  EXPECT_LT(relative_l2(fast.force_n, ref.force_n), 2e-2) << to_string(c.model);
  RecordProperty("relative_l2", std::to_string(err));
}

INSTANTIATE_TEST_SUITE_P(
    EveryForceModel, AgainstReference,
    ::testing::Values(ModelCase{ForceModelKind::spring, {4.0, 0.0}, 1},
                      ModelCase{ForceModelKind::kelvin_voigt, {4.0, 5e-6, 0.0}, 2},
                      ModelCase{ForceModelKind::hertz, {1e9, 10e-9, 0.0}, 2},
                      ModelCase{ForceModelKind::dmt, {1e9, 10e-9, 1e-19, 0.3e-9, 0.0}, 4},
                      ModelCase{ForceModelKind::dmt_viscous, {1e9, 10e-9, 1e-19, 0.3e-9, 0.0, 200.0}, 4}),
    [](const auto& info) {
      return std::string(to_string(info.param.model)) + "_" + std::to_string(info.index);
    });

TEST(ForwardSolver, ChirpSampledDriveAndOpticalLeverMatchReference) {
  ProbeSpec spec = paper_probe();
  spec.sensor = Sensor::optical_lever;
  const ModalModel modal(spec);
  auto backend = make_cpu_backend(1);
  Window chirp = sine_window(2000, 2e-9, 10000.0);
  chirp.drive.kind = DriveKind::chirp;
  chirp.drive.chirp_hz_per_s = 2e7;
  const auto pc = full_params({}, chirp);
  EXPECT_LT(relative_l2(simulate_one(*backend, modal, ForceModelKind::none, chirp, pc, ModalState::rest(8)).signal,
                        reference_simulate(modal, ForceModelKind::none, chirp, pc, ModalState::rest(8)).signal),
            1e-4);
  // A sampled drive: the same sine given sample by sample.
  Window sampled = sine_window(2000);
  sampled.drive.kind = DriveKind::sampled;
  for (int i = 0; i < 2000; ++i)
    sampled.drive.base_m.push_back(2e-9 * std::sin(2 * std::numbers::pi * 25600.0 * i * 1e-7));
  Window sine = sine_window(2000);
  const auto ps = full_params({}, sine);
  EXPECT_LT(relative_l2(simulate_one(*backend, modal, ForceModelKind::none, sampled, ps, ModalState::rest(8)).signal,
                        reference_simulate(modal, ForceModelKind::none, sine, ps, ModalState::rest(8)).signal),
            1e-3);
}

TEST(ForwardSolver, StableAtStepsFarBeyondExplicitLimit) {
  // omega_8 dt = 25: explicit RK4 diverges; the exact transition matrix does not.
  const ModalModel modal(paper_probe());
  auto backend = make_cpu_backend(1);
  Window w = sine_window(400, 2e-9, 25600.0, 1e-6);
  const auto p = full_params({4.0, 20e-9}, w);
  const ForwardOutput out = simulate_one(*backend, modal, ForceModelKind::spring, w, p, ModalState::rest(8));
  double peak = 0;
  for (double u : out.signal) {
    ASSERT_TRUE(std::isfinite(u));
    peak = std::max(peak, std::abs(u));
  }
  EXPECT_LT(peak, 1e-6);
  const auto rk4 = odeint_rk4_simulate(modal, ForceModelKind::spring, w, p, ModalState::rest(8));
  EXPECT_FALSE(std::isfinite(rk4.back()) && std::abs(rk4.back()) < 1e-6) << "RK4 should be unstable here";
}

TEST(ForwardSolver, StiffDamperStaysBoundedWhereExplicitForceWouldDiverge) {
  // c = 1e-3 N s/m: the damper's time constant (~50 ns) is below the sample period; the implicit
  // step-end force keeps the solution bounded (accuracy there is not claimed).
  const ModalModel modal(paper_probe());
  auto backend = make_cpu_backend(1);
  Window w = sine_window(3000);
  const auto p = full_params({4.0, 1e-3, 20e-9}, w);
  const ForwardOutput out = simulate_one(*backend, modal, ForceModelKind::kelvin_voigt, w, p, ModalState::rest(8));
  for (double u : out.signal) ASSERT_TRUE(std::isfinite(u) && std::abs(u) < 1e-6);
  for (double f : out.force_n) ASSERT_LE(f, 0.0);
}

TEST(ForwardSolver, SubstepsConvergeAtSecondOrder) {
  // Halving the step divides the difference to a fine solution by about four.
  const ModalModel modal(paper_probe());
  auto backend = make_cpu_backend(1);
  Window w = sine_window(2000);
  const auto p = full_params({1e9, 10e-9, 25e-9}, w);
  const ModalState start = linear_steady_state(modal, 2e-9, 25600.0, 0.0, 0.0);
  auto run = [&](int k) { return simulate_one(*backend, modal, ForceModelKind::hertz, w, p, start, k).signal; };
  const auto fine = run(32);
  const double e1 = relative_l2(run(2), fine), e2 = relative_l2(run(4), fine);
  EXPECT_GT(e1 / e2, 3.0);
  EXPECT_LT(e1 / e2, 5.0);
}

TEST(ForwardSolver, TwoContiguousWindowsEqualOneLongWindow) {
  const ModalModel modal(paper_probe());
  auto backend = make_cpu_backend(1);
  Window whole = sine_window(4000);
  const auto p = full_params({4.0, 30e-9}, whole);
  const ForwardOutput one = simulate_one(*backend, modal, ForceModelKind::spring, whole, p, ModalState::rest(8));
  Window a = sine_window(2000), b = sine_window(2000, 2e-9, 25600.0, 1e-7, 2000 * 1e-7);
  const ForwardOutput first = simulate_one(*backend, modal, ForceModelKind::spring, a, p, ModalState::rest(8));
  const ForwardOutput second = simulate_one(*backend, modal, ForceModelKind::spring, b, p, first.end_state[0]);
  std::vector<double> joined = first.signal;
  joined.insert(joined.end(), second.signal.begin(), second.signal.end());
  EXPECT_LT(relative_l2(joined, one.signal), 1e-12);
}

TEST(ForwardSolver, BatchOfManySetsAgreesWithSetsSolvedAlone) {
  const ModalModel modal(paper_probe());
  auto backend = make_cpu_backend(2);
  Window w = sine_window(1500);
  for (int i = 0; i < 1500; ++i) w.deflection_m[i] = 1e-8 * std::sin(i * 0.01);
  const StepCoefficients step = make_step_coefficients(modal, w.sample_period_s);
  const int S = 37;  // not a multiple of the block size
  std::vector<double> soa(6 * S);
  for (int s = 0; s < S; ++s) {
    const auto p = full_params({1.0 + 0.3 * s, 20e-9 + 1e-9 * s}, w);
    for (int k = 0; k < 6; ++k) soa[k * S + s] = p[k];
  }
  const ModalState rest = ModalState::rest(8);
  ForwardBatch batch;
  batch.n_sets = S;
  batch.params = soa;
  batch.initial = std::span<const ModalState>(&rest, 1);
  batch.want_signal = true;
  ForwardOutput out;
  backend->solve({&modal, &step, ForceModelKind::spring, &w, 1}, batch, out);
  for (int s : {0, 15, 16, 36}) {
    const auto p = full_params({1.0 + 0.3 * s, 20e-9 + 1e-9 * s}, w);
    const ForwardOutput alone = simulate_one(*backend, modal, ForceModelKind::spring, w, p, rest);
    double cost = 0;
    for (int n = 0; n < 1500; ++n) cost += std::pow(w.deflection_m[n] - alone.signal[n], 2);
    EXPECT_NEAR(out.cost[s], cost, 1e-12 * cost);
    EXPECT_EQ(out.signal[static_cast<std::size_t>(s) * 1500 + 1499], alone.signal[1499]);
  }
}

TEST(ForwardSolver, MalformedBatchIsACallerError) {
  const ModalModel modal(paper_probe());
  auto backend = make_cpu_backend(1);
  Window w = sine_window(100);
  const StepCoefficients wrong = make_step_coefficients(modal, 2e-7);
  const ModalState rest = ModalState::rest(8);
  std::vector<double> p = full_params({4.0, 1e-8}, w);
  ForwardBatch batch;
  batch.n_sets = 1;
  batch.params = p;
  batch.initial = std::span<const ModalState>(&rest, 1);
  ForwardOutput out;
  EXPECT_THROW(backend->solve({&modal, &wrong, ForceModelKind::spring, &w, 1}, batch, out), std::invalid_argument);
}

}  // namespace
}  // namespace tipforce
