// Is a reported 1-sigma the data's own information, neither inflated nor overconfident? For a
// window in steady tapping the Cramér–Rao bound on each unknown follows from the signal's
// sensitivities alone: F = JᵀJ / noise², J by central differences of the independent reference
// integrator at the truth. It brackets what an efficient, honest inversion reports: no better than
// with the window's start known exactly (the unknowns' block of F), no worse than with modes 1 and
// 2's start free (the four nuisance unknowns the inversion fits, with no prior). The test inverts a
// run of continued windows of constant truth and holds each unknown's reported sigma between those
// bounds (as medians over the windows) and the actual errors to that sigma, for every force model.
//
// It also records why the demo's stiff substrate reports sigma_k / k near 14 %: at a 12 N/m
// contact, 9 x the lever's stiffness, in steady tapping at 45 nm from a ~60 nm free amplitude, two
// drive periods at 0.1 nm noise determine k to 13 % even with the start known and to 19 % with it
// free (the bounds printed below); a 1 MHz window of 1250 samples, about 32 periods, to 5 %.
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <tuple>
#include <random>
#include <vector>

#include "test_support.hpp"
#include "tipforce/percentile.hpp"

namespace tipforce {
namespace {

using Unknown = std::tuple<std::string, double, double>;  // name, low, high

struct Case {
  std::string label;
  ForceModelKind model;
  std::vector<double> truth;  // the model's parameters, SPEC section 1 order
  std::vector<Unknown> unknowns;
  double sample_period_s;
  int samples_per_window;
  int windows;
  friend void PrintTo(const Case& c, std::ostream* os) { *os << c.label; }  // not its bytes
};

constexpr double kNoiseM = 1e-10;   // the demo's 0.1 nm
constexpr double kDriveM = 0.6e-9;  // ~60 nm free amplitude at f1, as the demo

double median(const std::vector<double>& v) { return percentile(v, 0.5); }

struct Bounds {
  std::vector<double> known_start, free_start;  // sigma per unknown
};

// The Cramér–Rao bounds on the unknowns for window w from `start` (the true state at its first
// sample). index[j]: unknown j's place among the model's parameters.
Bounds cramer_rao(const ModalModel& modal, const Case& c, const std::vector<int>& index, const Window& w,
                  const ModalState& start) {
  constexpr int kStartModes = 2;
  const int n = static_cast<int>(w.deflection_m.size()), m = static_cast<int>(index.size()), np = m + 2 * kStartModes;
  Eigen::MatrixXd J(n, np);
  for (int p = 0; p < np; ++p) {
    double step = 0;
    auto signal = [&](double sign) {
      std::vector<double> params = c.truth;
      ModalState s = start;
      if (p < m) {
        double& v = params[static_cast<std::size_t>(index[static_cast<std::size_t>(p)])];
        // Lengths (h) by 10 pm, every other parameter by 1e-3 of its value.
        step = std::get<0>(c.unknowns[static_cast<std::size_t>(p)]) == "h_m" ? 1e-11 : 1e-3 * std::abs(v);
        v += sign * step;
      } else {
        const int i = (p - m) / 2;
        if ((p - m) % 2 == 0) s.q[static_cast<std::size_t>(i)] += sign * (step = 1e-11);
        else s.v[static_cast<std::size_t>(i)] += sign * (step = 1e-11 * modal.modes()[static_cast<std::size_t>(i)].omega_rad_per_s);
      }
      return reference_simulate(modal, c.model, w, testing::full_params(params, w), s).signal;
    };
    const std::vector<double> up = signal(+1), down = signal(-1);
    for (int i = 0; i < n; ++i) J(i, p) = (up[static_cast<std::size_t>(i)] - down[static_cast<std::size_t>(i)]) / (2 * step);
  }
  const Eigen::MatrixXd F = J.transpose() * J / (kNoiseM * kNoiseM);
  const Eigen::MatrixXd known = F.topLeftCorner(m, m).inverse(), free = F.inverse();
  Bounds b;
  for (int j = 0; j < m; ++j) {
    b.known_start.push_back(std::sqrt(known(j, j)));
    b.free_start.push_back(std::sqrt(free(j, j)));
  }
  return b;
}

struct UnknownRecord {
  std::vector<double> over_known, over_free, z, sigma_rel, known_rel, free_rel;
};

class Efficiency : public ::testing::TestWithParam<Case> {};

TEST_P(Efficiency, ReportedSigmaIsTheDatasInformation) {
  const Case c = GetParam();
  const ModalModel modal(testing::paper_probe());
  const double drive_hz = modal.modes()[0].frequency_hz;
  const auto names = force_model_parameters(c.model);
  ParameterSpace space(c.model);
  std::vector<int> index;
  for (const auto& [name, low, high] : c.unknowns) {
    space.make_unknown(name, low, high);
    index.push_back(static_cast<int>(std::find(names.begin(), names.end(), name) - names.begin()));
  }
  for (std::size_t j = 0; j < names.size(); ++j)
    if (std::find(index.begin(), index.end(), static_cast<int>(j)) == index.end()) space.fix(names[j], c.truth[j]);
  const int m = static_cast<int>(index.size());
  auto backend = make_cpu_backend(2);
  Inverter inv(ProbeModel{"p", modal, space, testing::unbudgeted_options()}, *backend);
  const int n = c.samples_per_window;

  // Steady tapping: eight decay times of mode 1 from the free steady state.
  const double tau_s = 2 * modal.modes()[0].quality_factor / modal.modes()[0].omega_rad_per_s;
  const int lead = static_cast<int>(8 * tau_s / c.sample_period_s);
  const Window lead_in = testing::sine_window(lead, kDriveM, drive_hz, c.sample_period_s, -lead * c.sample_period_s);
  ModalState state = reference_simulate(modal, c.model, lead_in, testing::full_params(c.truth, lead_in),
                                        linear_steady_state(modal, kDriveM, drive_hz, 0.0, lead_in.t0_s))
                         .end_state;

  std::mt19937_64 rng(20261203);
  std::normal_distribution<double> noise(0.0, kNoiseM);
  std::vector<UnknownRecord> rec(static_cast<std::size_t>(m));
  int not_ok = 0;
  for (int px = 0; px < c.windows; ++px) {
    Window w = testing::sine_window(n, kDriveM, drive_hz, c.sample_period_s, px * n * c.sample_period_s);
    const ReferenceResult ref = reference_simulate(modal, c.model, w, testing::full_params(c.truth, w), state);
    const Bounds b = px == 0 ? Bounds{} : cramer_rao(modal, c, index, w, state);
    state = ref.end_state;
    for (int i = 0; i < n; ++i) w.deflection_m[static_cast<std::size_t>(i)] = ref.signal[static_cast<std::size_t>(i)] + noise(rng);
    w.initial = px == 0 ? InitialState::unknown : InitialState::continued;
    const Estimate e = inv.invert(w);
    if (px == 0) continue;  // the cold start: its own bound is the free start's, and one window says little
    if (e.status != EstimateStatus::ok || static_cast<int>(e.values.size()) != m) {
      ++not_ok;
      continue;
    }
    for (int j = 0; j < m; ++j) {
      const std::size_t u = static_cast<std::size_t>(j);
      const double truth = c.truth[static_cast<std::size_t>(index[u])];
      rec[u].over_known.push_back(e.sigma[u] / b.known_start[u]);
      rec[u].over_free.push_back(e.sigma[u] / b.free_start[u]);
      rec[u].z.push_back((e.values[u] - truth) / e.sigma[u]);
      rec[u].sigma_rel.push_back(e.sigma[u] / truth);
      rec[u].known_rel.push_back(b.known_start[u] / truth);
      rec[u].free_rel.push_back(b.free_start[u] / truth);
    }
  }
  for (int j = 0; j < m; ++j) {
    const UnknownRecord& r = rec[static_cast<std::size_t>(j)];
    const std::string& name = std::get<0>(c.unknowns[static_cast<std::size_t>(j)]);
    double z2 = 0;
    for (double v : r.z) z2 += v * v;
    const double rms_z = r.z.empty() ? NAN : std::sqrt(z2 / static_cast<double>(r.z.size()));
    std::printf("  %s, %s: sigma / value reported %.2f %% (median), Cramer-Rao %.2f %% start known, %.2f %% start free; "
                "reported / bound %.2f (known) %.2f (free); rms (estimate - truth) / sigma %.2f over %zu windows, %d not OK\n",
                c.label.c_str(), name.c_str(), 100 * median(r.sigma_rel), 100 * median(r.known_rel), 100 * median(r.free_rel),
                median(r.over_known), median(r.over_free), rms_z, r.z.size(), not_ok);
    ASSERT_GE(r.z.size(), static_cast<std::size_t>(c.windows * 3 / 4)) << "too few windows answered OK";
    // The bounds' own scatter (the window's s2, the linearisation at the estimate rather than the
    // truth, the bounds' information) leaves ~10 % either way.
    EXPECT_GE(median(r.over_known), 0.8) << name << ": sigma below the information of a window whose start is known: overconfident";
    EXPECT_LE(median(r.over_free), 1.25) << name << ": sigma above the information of a window without a start prior: inflated";
    EXPECT_GE(rms_z, 0.65) << name << ": the estimates scatter far less than the sigma they report";
    EXPECT_LE(rms_z, 1.4) << name << ": the estimates scatter more than the sigma they report";
  }
}

const Unknown kK{"k_n_per_m", 0.5, 20.0}, kH{"h_m", 10e-9, 70e-9}, kE{"e_star_pa", 1e7, 1e11};

INSTANTIATE_TEST_SUITE_P(
    SteadyTapping, Efficiency,
    ::testing::Values(Case{"substrate_5mhz", ForceModelKind::spring, {12.0, 45e-9}, {kK, kH}, 2e-7, 400, 40},
                      Case{"cell_5mhz", ForceModelKind::spring, {3.0, 35e-9}, {kK, kH}, 2e-7, 400, 40},
                      Case{"substrate_1mhz", ForceModelKind::spring, {12.0, 45e-9}, {kK, kH}, 1e-6, 1250, 24},
                      // Every other force model at 1 MHz, the unknowns a user fits (honesty_test's
                      // HonestyEveryModel; the tip's radius, Hamaker constant and a0 fixed).
                      Case{"kelvin_voigt_1mhz", ForceModelKind::kelvin_voigt, {4.0, 5e-6, 35e-9},
                           {kK, Unknown{"c_ns_per_m", 0.0, 5e-5}, kH}, 1e-6, 1250, 24},
                      Case{"hertz_1mhz", ForceModelKind::hertz, {1e9, 10e-9, 35e-9}, {kE, kH}, 1e-6, 1250, 24},
                      Case{"dmt_1mhz", ForceModelKind::dmt, {1e9, 10e-9, 1e-19, 0.3e-9, 35e-9}, {kE, kH}, 1e-6, 1250, 24},
                      Case{"dmt_viscous_1mhz", ForceModelKind::dmt_viscous, {1e9, 10e-9, 1e-19, 0.3e-9, 35e-9, 200.0},
                           {kE, kH, Unknown{"eta_pa_s", 0.0, 1e4}}, 1e-6, 1250, 24},
                      Case{"hertz_5mhz", ForceModelKind::hertz, {1e9, 10e-9, 35e-9}, {kE, kH}, 2e-7, 400, 40}),
    [](const ::testing::TestParamInfo<Case>& i) { return i.param.label; });

}  // namespace
}  // namespace tipforce
