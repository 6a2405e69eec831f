// The setpoint advisor (issue 13) against the reference integrator: its free-amplitude gain, its
// sensitivities, its predictions of the next window (held and corrected) and the cases it must
// refuse; and its configuration table.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "test_support.hpp"
#include "tipforce/setpoint_advisor.hpp"
#include "tipforce/tipforce.hpp"

namespace tipforce {
namespace {

constexpr double kDt = 2e-7;      // 5 MHz
constexpr int kN = 1000;          // five drive periods
constexpr double kF = 25468.9;
constexpr double kA0 = 20e-9;     // free amplitude

double peak_of(const std::vector<double>& force) {
  double p = 0;
  for (double f : force) p = std::max(p, -f);
  return p;
}

// Steady tapping on a spring surface, made and continued by the reference integrator.
class Tapping {
 public:
  Tapping(double k, double h_m, int modes = 3) : modal_(testing::paper_probe(modes)) {
    gain_ = free_amplitude_per_drive_amplitude(modal_, kF);
    drive_m_ = kA0 / gain_;
    full_ = {k, h_m, drive_m_, kF, 0, 0};
    const double tau = 2 * modal_.modes()[0].quality_factor / modal_.modes()[0].omega_rad_per_s;
    const int lead = static_cast<int>(6 * tau / kDt);
    Window w = testing::sine_window(lead, drive_m_, kF, kDt, -lead * kDt);
    state_ = reference_simulate(modal_, ForceModelKind::spring, w, full_,
                                linear_steady_state(modal_, drive_m_, kF, 0, w.t0_s)).end_state;
  }
  // The next window of the scan with the given parameters; advances the state.
  Window next(const std::vector<double>& full, double noise_m, std::mt19937_64& rng, double* peak_n = nullptr) {
    Window w = testing::sine_window(kN, full[2], kF, kDt, t_s_);
    w.initial = windows_ == 0 ? InitialState::unknown : InitialState::continued;
    const ReferenceResult r = reference_simulate(modal_, ForceModelKind::spring, w, full, state_);
    std::normal_distribution<double> noise(0.0, noise_m);
    for (int i = 0; i < kN; ++i) w.deflection_m[static_cast<std::size_t>(i)] = r.signal[static_cast<std::size_t>(i)] + noise(rng);
    if (peak_n) *peak_n = peak_of(r.force_n);
    state_ = r.end_state;
    t_s_ += kN * kDt;
    ++windows_;
    return w;
  }
  // What the next window would give from the present state, without advancing.
  double peek_peak(const std::vector<double>& full) const {
    const Window w = testing::sine_window(kN, full[2], kF, kDt, t_s_);
    return peak_of(reference_simulate(modal_, ForceModelKind::spring, w, full, state_).force_n);
  }
  const ModalModel& modal() const { return modal_; }
  const ModalState& state() const { return state_; }
  double t_s() const { return t_s_; }
  double gain() const { return gain_; }
  const std::vector<double>& full() const { return full_; }

 private:
  ModalModel modal_;
  double gain_ = 0, drive_m_ = 0;
  std::vector<double> full_;
  ModalState state_;
  double t_s_ = 0;
  int windows_ = 0;
};

ParameterSpace spring_space() {
  ParameterSpace s(ForceModelKind::spring);
  s.make_unknown("k_n_per_m", 0.5, 20);
  s.make_unknown("h_m", 5e-9, 30e-9);
  return s;
}

// A fit that is the truth, with a tiny covariance: what the advisor makes of a perfect estimate.
struct OracleFit {
  Window window;
  Estimate estimate;
  std::vector<double> full;
  FittedWindow view(const ModalState& state, double end_t_s) {
    return FittedWindow{&window, &estimate, &state, end_t_s, full};
  }
};
OracleFit oracle(const Tapping& t, const Window& answered) {
  OracleFit o;
  o.window = answered;
  o.full = t.full();
  o.estimate.names = {"k_n_per_m", "h_m"};
  o.estimate.values = {t.full()[0], t.full()[1]};
  o.estimate.sigma = {1e-6 * t.full()[0], 1e-15};
  o.estimate.determined = {true, true};
  o.estimate.covariance = Eigen::MatrixXd::Zero(2, 2);
  o.estimate.covariance(0, 0) = std::pow(o.estimate.sigma[0], 2);
  o.estimate.covariance(1, 1) = std::pow(o.estimate.sigma[1], 2);
  o.estimate.peak_force_n = 1e-9;
  return o;
}

TEST(SetpointAdvisor, FreeAmplitudeGainIsTheReferenceIntegratorsFreeSteadyState) {
  // From rest, with the surface out of reach, for 12 decay times of mode 1 at 1 MHz: the transient
  // is down to e^-12, and the last period's amplitude is the steady state's.
  const ModalModel modal(testing::paper_probe(3));
  const double tau = 2 * modal.modes()[0].quality_factor / modal.modes()[0].omega_rad_per_s;
  const double dt = 1e-6, a = 0.1e-9;
  const int n = static_cast<int>(12 * tau / dt);
  const Window w = testing::sine_window(n, a, kF, dt);
  const std::vector<double> full{1.0, 1e-3, a, kF, 0, 0};
  const ReferenceResult r = reference_simulate(modal, ForceModelKind::spring, w, full, ModalState::rest(3));
  double lo = INFINITY, hi = -INFINITY;
  const int period = static_cast<int>(std::ceil(1.0 / (kF * dt)));
  for (int i = n - 2 * period; i < n; ++i) {
    lo = std::min(lo, r.signal[static_cast<std::size_t>(i)]);
    hi = std::max(hi, r.signal[static_cast<std::size_t>(i)]);
  }
  const double measured = 0.5 * (hi - lo);
  // Sampled at 1 MHz the extremes are missed by up to (1 - cos(pi f dt)) ~ 3e-3.
  EXPECT_NEAR(free_amplitude_per_drive_amplitude(modal, kF) * a, measured, 4e-3 * measured);
}

TEST(SetpointAdvisor, SensitivityToZMatchesTheReferenceIntegratorsFiniteDifference) {
  Tapping t(10.0, 16e-9);
  std::mt19937_64 rng(1);
  const Window w = t.next(t.full(), 0, rng);
  OracleFit o = oracle(t, w);
  AdvisorOptions opt;
  opt.max_peak_force_n = 1e-6;  // far away: only the hold prediction and sensitivities
  SetpointAdvisor advisor(t.modal(), spring_space(), opt);
  auto backend = make_cpu_backend(1);
  const Advice a = advisor.advise(o.view(t.state(), t.t_s()), *backend);
  ASSERT_EQ(a.status, AdviceStatus::under_limit) << a.reason;
  const double dz = 0.1e-9;
  std::vector<double> up = t.full(), down = t.full();
  up[1] += dz;
  down[1] -= dz;
  const double ref_dpdz = (t.peek_peak(up) - t.peek_peak(down)) / (2 * dz);
  EXPECT_NEAR(a.hold_peak_force_n, t.peek_peak(t.full()), 1e-3 * a.hold_peak_force_n);
  EXPECT_LT(ref_dpdz, 0);
  EXPECT_NEAR(a.dpeak_dz_n_per_m, ref_dpdz, 0.01 * std::abs(ref_dpdz));
  std::vector<double> more = t.full();
  more[2] *= 1.01;
  std::vector<double> less = t.full();
  less[2] *= 0.99;
  const double ref_dpda = (t.peek_peak(more) - t.peek_peak(less)) / (0.02 * t.full()[2] * t.gain());
  EXPECT_NEAR(a.dpeak_dfree_amplitude_n_per_m, ref_dpda, 0.02 * std::abs(ref_dpda) + 1e-3);
  EXPECT_NEAR(a.current_free_amplitude_m, kA0, 1e-12 * kA0);
}

TEST(SetpointAdvisor, CorrectionPutsTheReferencesNextPeakForceAtTheAim) {
  Tapping t(10.0, 16e-9);
  std::mt19937_64 rng(1);
  const Window w = t.next(t.full(), 0, rng);
  OracleFit o = oracle(t, w);
  AdvisorOptions opt;
  opt.max_peak_force_n = 0.5 * t.peek_peak(t.full());
  opt.min_free_amplitude_m = 18e-9;
  SetpointAdvisor advisor(t.modal(), spring_space(), opt);
  auto backend = make_cpu_backend(1);
  const Advice a = advisor.advise(o.view(t.state(), t.t_s()), *backend);
  ASSERT_EQ(a.status, AdviceStatus::correction) << a.reason;
  EXPECT_GT(a.z_offset_m, 0);
  EXPECT_LE(a.z_offset_m, opt.max_z_step_m);
  EXPECT_LE(a.free_amplitude_m, kA0);
  EXPECT_GE(a.free_amplitude_m, opt.min_free_amplitude_m);
  // The aim is met from below, within the iteration's tolerance.
  const double aim = (1 - opt.margin) * opt.max_peak_force_n;
  EXPECT_LE(a.predicted_peak_force_n + opt.sigma_multiplier * a.predicted_sigma_n, aim * (1 + 1e-9));
  EXPECT_GE(a.predicted_peak_force_n + opt.sigma_multiplier * a.predicted_sigma_n,
            aim - opt.aim_tolerance_rel * opt.max_peak_force_n);
  // And the reference integrator, given those setpoints, agrees.
  std::vector<double> corrected = t.full();
  corrected[1] += a.z_offset_m;
  corrected[2] = a.free_amplitude_m / t.gain();
  EXPECT_NEAR(t.peek_peak(corrected), a.predicted_peak_force_n, 2e-3 * a.predicted_peak_force_n);
  EXPECT_GT(a.forward_solves, 0);
}

TEST(SetpointAdvisor, WithoutAnAmplitudeRangeTheFreeAmplitudeStaysAndTheRetractionIsBounded) {
  Tapping t(10.0, 16e-9);
  std::mt19937_64 rng(1);
  const Window w = t.next(t.full(), 0, rng);
  OracleFit o = oracle(t, w);
  AdvisorOptions opt;
  opt.max_peak_force_n = 0.2 * t.peek_peak(t.full());
  opt.max_z_step_m = 0.01e-9;  // far too little
  SetpointAdvisor advisor(t.modal(), spring_space(), opt);
  auto backend = make_cpu_backend(1);
  const Advice a = advisor.advise(o.view(t.state(), t.t_s()), *backend);
  ASSERT_EQ(a.status, AdviceStatus::out_of_range) << a.reason;
  EXPECT_DOUBLE_EQ(a.free_amplitude_m, a.current_free_amplitude_m);
  EXPECT_NEAR(a.z_offset_m, opt.max_z_step_m, 1e-18);
  EXPECT_GT(a.predicted_peak_force_n, opt.max_peak_force_n);
  EXPECT_LT(a.predicted_peak_force_n, a.hold_peak_force_n);
}

// The whole chain on noisy data: the Inverter's fit of each window, the advisor's prediction of
// the next, the reference integrator's truth. Soft and hard, held (no correction applied).
class HeldPrediction : public ::testing::TestWithParam<double> {};

TEST_P(HeldPrediction, IsWithinTwoSigmaOfTheReferenceForNinetyPercentOfWindows) {
  const double k = GetParam();
  Tapping t(k, 16e-9);
  std::mt19937_64 rng(7);
  auto backend = make_cpu_backend(1);
  ProbeModel probe{"t", t.modal(), spring_space(), {}};
  probe.options.swarm_size = 24;
  probe.options.max_generations = 25;
  Inverter inverter(probe, *backend);
  AdvisorOptions opt;
  opt.max_peak_force_n = 1e-6;
  SetpointAdvisor advisor(t.modal(), spring_space(), opt);
  int predictions = 0, within = 0;
  double rel_sigma_sum = 0, z2_sum = 0;
  Advice last;
  for (int i = 0; i < 40; ++i) {
    double truth = 0;
    Window w = t.next(t.full(), 5e-11, rng, &truth);
    if (last.status == AdviceStatus::under_limit) {
      ++predictions;
      within += std::abs(last.hold_peak_force_n - truth) <= 2 * last.hold_sigma_n;
      rel_sigma_sum += last.hold_sigma_n / truth;
      z2_sum += std::pow((last.hold_peak_force_n - truth) / last.hold_sigma_n, 2);
    }
    const Estimate e = inverter.invert(w);
    last = advisor.advise(FittedWindow{&w, &e, inverter.last_end_state(), inverter.last_end_t_s(),
                                       inverter.last_full_params()},
                          *backend);
  }
  std::printf("k = %g N/m: %d of %d held predictions within 2 sigma, mean sigma %.1f %% of the value, rms error "
              "%.2f sigma\n", k, within, predictions, 100 * rel_sigma_sum / predictions, std::sqrt(z2_sum / predictions));
  ASSERT_GE(predictions, 35);
  EXPECT_GE(within, 0.9 * predictions);
  // Not honest by being vague: the errors are of the size sigma says (measured: rms 0.6-0.8 sigma,
  // the quadratic term adding ~15 % to sigma), and sigma is a fraction of the value.
  EXPECT_GT(std::sqrt(z2_sum / predictions), 0.4);
  EXPECT_LT(rel_sigma_sum / predictions, 0.25);
}

INSTANTIATE_TEST_SUITE_P(SoftAndHard, HeldPrediction, ::testing::Values(1.0, 10.0));

TEST(SetpointAdvisor, FitsNotTrustedGetNoAdviceAndSaySo) {
  Tapping t(10.0, 16e-9);
  std::mt19937_64 rng(1);
  const Window w = t.next(t.full(), 0, rng);
  AdvisorOptions opt;
  opt.max_peak_force_n = 1e-9;
  SetpointAdvisor advisor(t.modal(), spring_space(), opt);
  auto backend = make_cpu_backend(1);
  for (EstimateStatus s : {EstimateStatus::rejected, EstimateStatus::not_converged}) {
    OracleFit o = oracle(t, w);
    o.estimate.status = s;
    o.estimate.message = "relative misfit 0.5 above 0.3";
    const Advice a = advisor.advise(o.view(t.state(), t.t_s()), *backend);
    EXPECT_EQ(a.status, AdviceStatus::no_advice);
    EXPECT_NE(a.reason.find(s == EstimateStatus::rejected ? "REJECTED" : "NOT_CONVERGED"), std::string::npos) << a.reason;
    EXPECT_NE(a.reason.find("misfit 0.5"), std::string::npos) << a.reason;
    EXPECT_TRUE(std::isnan(a.predicted_peak_force_n));
    EXPECT_EQ(a.z_offset_m, 0);
    EXPECT_EQ(a.forward_solves, 0);
  }
  OracleFit no_state = oracle(t, w);
  EXPECT_EQ(advisor.advise(FittedWindow{&no_state.window, &no_state.estimate, nullptr, t.t_s(), no_state.full}, *backend).status,
            AdviceStatus::no_advice);
  OracleFit sampled = oracle(t, w);
  sampled.window.drive.kind = DriveKind::sampled;
  sampled.window.drive.base_m.assign(kN, 0.0);
  const Advice a = advisor.advise(sampled.view(t.state(), t.t_s()), *backend);
  EXPECT_EQ(a.status, AdviceStatus::no_advice);
  EXPECT_NE(a.reason.find("sine drive"), std::string::npos) << a.reason;
}

TEST(SetpointAdvisor, AWindowWithoutContactIsUnderTheLimit) {
  // Retracted beyond the tip's reach: the fit is NOT_CONVERGED only because the contact's
  // stiffness is undetermined, and its end state is kept.
  Tapping t(10.0, 25e-9);
  std::mt19937_64 rng(1);
  const Window w = t.next(t.full(), 0, rng);
  OracleFit o = oracle(t, w);
  o.estimate.status = EstimateStatus::not_converged;
  o.estimate.peak_force_n = 0;
  o.estimate.determined = {false, false};
  o.estimate.message = "parameters not identifiable from this window (singular Gauss-Newton matrix)";
  AdvisorOptions opt;
  opt.max_peak_force_n = 1e-9;
  SetpointAdvisor advisor(t.modal(), spring_space(), opt);
  auto backend = make_cpu_backend(1);
  const Advice a = advisor.advise(o.view(t.state(), t.t_s()), *backend);
  EXPECT_EQ(a.status, AdviceStatus::under_limit) << a.reason;
  EXPECT_EQ(a.hold_peak_force_n, 0);
  EXPECT_NE(a.reason.find("no contact"), std::string::npos) << a.reason;
}

TEST(SetpointAdvisor, OptionsThatCannotWorkAreRefusedByName) {
  const ModalModel modal(testing::paper_probe(3));
  AdvisorOptions o;
  EXPECT_NE(advisor_options_problem(o).find("max_peak_force_n"), std::string::npos);
  o.max_peak_force_n = 1e-9;
  EXPECT_EQ(advisor_options_problem(o), "");
  for (auto [field, bad] : std::vector<std::pair<std::string, AdvisorOptions>>{
           {"margin", [] { AdvisorOptions a; a.max_peak_force_n = 1e-9; a.margin = 1.0; return a; }()},
           {"sigma_multiplier", [] { AdvisorOptions a; a.max_peak_force_n = 1e-9; a.sigma_multiplier = -1; return a; }()},
           {"min_free_amplitude_m", [] { AdvisorOptions a; a.max_peak_force_n = 1e-9; a.min_free_amplitude_m = -1e-9; return a; }()},
           {"max_z_step_m", [] { AdvisorOptions a; a.max_peak_force_n = 1e-9; a.max_z_step_m = INFINITY; return a; }()}}) {
    EXPECT_NE(advisor_options_problem(bad).find(field), std::string::npos) << field;
    EXPECT_THROW(SetpointAdvisor(modal, spring_space(), bad), std::invalid_argument) << field;
  }
  EXPECT_THROW(SetpointAdvisor(modal, ParameterSpace(ForceModelKind::none), o), std::invalid_argument);
}

const char* kProbe =
    "[probe.tip]\nf1_hz = 25000\nk_c_n_per_m = 1.3\nmodel = \"spring\"\n"
    "unknowns = { k_n_per_m = [0.5, 20.0], h_m = [0.0, 60e-9] }\n";

TEST(AdvisorConfig, TableIsReadWithItsDefaults) {
  const Config c = parse_config(std::string(kProbe) + "[probe.tip.advisor]\nmax_peak_force_n = 2e-9\n"
                                "min_free_amplitude_m = 18e-9\nmax_z_step_m = 1e-9\n", "c.toml");
  ASSERT_TRUE(c.probes.at("tip").advisor.has_value());
  const AdvisorOptions& a = *c.probes.at("tip").advisor;
  EXPECT_DOUBLE_EQ(a.max_peak_force_n, 2e-9);
  EXPECT_DOUBLE_EQ(a.min_free_amplitude_m, 18e-9);
  EXPECT_DOUBLE_EQ(a.max_z_step_m, 1e-9);
  EXPECT_DOUBLE_EQ(a.margin, AdvisorOptions{}.margin);
  EXPECT_EQ(c.daemon.setpoint_channel, "TIPFORCE_SETPOINT");
  EXPECT_FALSE(parse_config(kProbe, "c.toml").probes.at("tip").advisor.has_value());
}

TEST(AdvisorConfig, ProblemsNameFileKeyAndProblem) {
  auto error_of = [](const std::string& text) {
    try {
      parse_config(text, "c.toml");
    } catch (const ConfigError& e) {
      return std::string(e.what());
    }
    return std::string("(accepted)");
  };
  const std::string p(kProbe);
  EXPECT_EQ(error_of(p + "[probe.tip.advisor]\nmargin = 0.1\n"),
            "c.toml: probe.tip.advisor.max_peak_force_n: missing (the limit on the peak force, N)");
  EXPECT_EQ(error_of(p + "[probe.tip.advisor]\nmax_peak_force_n = 2e-9\nmax_force = 1\n"),
            "c.toml: probe.tip.advisor.max_force: unknown key");
  EXPECT_NE(error_of(p + "[probe.tip.advisor]\nmax_peak_force_n = -1\n").find("probe.tip.advisor.max_peak_force_n: must be"),
            std::string::npos);
  EXPECT_NE(error_of(p + "[probe.tip.advisor]\nmax_peak_force_n = 2e-9\nmargin = 1.5\n").find("probe.tip.advisor.margin"),
            std::string::npos);
  EXPECT_NE(error_of(p + "[probe.tip.advisor]\nmax_peak_force_n = \"2 nN\"\n").find("expected a number"), std::string::npos);
  EXPECT_NE(error_of("[daemon]\nsetpoint_channel = \"TIPFORCE_ESTIMATE\"\n" + p).find("daemon.setpoint_channel: must differ"),
            std::string::npos);
  EXPECT_NE(error_of("[probe.tip]\nf1_hz = 25000\nk_c_n_per_m = 1.3\nmodel = \"none\"\n[probe.tip.advisor]\n"
                     "max_peak_force_n = 2e-9\n")
                .find("probe.tip.advisor: the model has no separation h_m"),
            std::string::npos);
}

}  // namespace
}  // namespace tipforce
