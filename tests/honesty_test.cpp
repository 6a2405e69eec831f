// Are the reported 1-sigma values true on long scans? SPEC section 2: on noisy synthetic data the
// truth lies within 2 sigma for >= 90 % of pixels, sigma is not inflated to get there (median
// sigma <= 10 % of the value), and what a continued window inherits from the previous fit must not
// grow window after window (the largest sigma <= 20 x the median). A scan of a thousand continued
// windows is what exposes a recursion that compounds: a 64-pixel line does not.
//
// HonestyEveryModel holds the same for every force model (spring, Kelvin-Voigt, Hertz, DMT, viscous
// DMT) on shorter scans at 1 and 5 MHz, with cold starts among them.
//
// The data come from the independent reference integrator (adaptive Dormand-Prince with located
// contact switches), the code path of `tipforce simulate`, never from the solver being tested.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <random>
#include <string>
#include <tuple>
#include <vector>

#include "test_support.hpp"

namespace tipforce {
namespace {

struct ScanSpec {
  const char* label;
  int samples_per_window;
  double sample_period_s;
  int pixels;
  int pixels_per_row;
  double noise_m;
  double substrate_h_m;  // the substrate's separation; the cell rises 15 nm above it
  int cold_every = 0;    // also invert every this many windows on its own, start unknown (0: none)
  std::map<std::string, double> drift = {};  // InversionOptions::parameter_drift_rel (empty: no pooling)
};

// The demo's sample: a soft cell (k 1.5-3 N/m, surface raised by up to 15 nm) on a stiff
// substrate (12 N/m), in raster order. The cell's rim is a jump in k that the tracker must hand to
// the swarm, the dome a smooth change that it must follow.
struct Truth {
  double k_n_per_m, h_m;
};
Truth cell_truth(int pixel, int pixels_per_row, int rows, double substrate_h_m) {
  const double x = pixel % pixels_per_row, y = pixel / pixels_per_row;
  const double u = (x - 0.55 * pixels_per_row) / (0.3 * pixels_per_row), v = (y - 0.5 * rows) / (0.45 * rows);
  const double r2 = u * u + v * v;
  if (r2 >= 1.0) return {12.0, substrate_h_m};
  const double dome = std::sqrt(1.0 - r2);
  return {1.5 + 1.5 * dome, substrate_h_m - 15e-9 * dome};
}

struct ParameterFigures {
  double within_two_sigma = 0;   // fraction of the windows
  double median_rel_sigma = 0;   // median of sigma / |value|
  double max_over_median = 0;    // largest sigma / median sigma, over the windows that determine it
  double max_sigma = 0;          // largest sigma of all
  int undetermined = 0;          // windows that say they hardly narrow the bounds of some unknown
  double within_three_sigma = 0;
  double median_rel_error = 0;   // median |value - truth| / truth
  // The errors' spread in sigmas on a robust scale (median |error / sigma| / 0.6745): 1 where the
  // sigmas are true, below 1 where they are inflated.
  double z_spread = 0;
};

struct ScanFigures {
  int windows = 0, answered = 0, not_ok = 0;
  ParameterFigures k, h;
  double seconds_simulate = 0, seconds_invert = 0;
  // The same data's sampled windows inverted as independent cold starts (INITIAL_UNKNOWN).
  int cold_windows = 0, cold_not_ok = 0;
  ParameterFigures cold_k, cold_h;
};

struct ParameterSamples {
  std::vector<double> truth, value, sigma;
  std::vector<bool> determined;
  void add(double t, const Estimate& e, int j) {
    truth.push_back(t);
    value.push_back(e.values[static_cast<std::size_t>(j)]);
    sigma.push_back(e.sigma[static_cast<std::size_t>(j)]);
    // A window counts as determining the parameter only if it determines every unknown: a valley
    // window that leaves k to its bounds leaves h wide too, through their trade-off.
    determined.push_back(std::all_of(e.determined.begin(), e.determined.end(), [](bool d) { return d; }));
  }
};

double median(std::vector<double> v) {
  if (v.empty()) return std::nan("");
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
  return v[v.size() / 2];
}

ParameterFigures figures(const ParameterSamples& p) {
  ParameterFigures f;
  std::vector<double> rel;
  int within = 0;
  double largest_determined = 0;
  for (std::size_t i = 0; i < p.truth.size(); ++i) {
    const double sigma = std::isnan(p.sigma[i]) ? INFINITY : p.sigma[i];
    within += std::abs(p.value[i] - p.truth[i]) <= 2 * sigma;
    rel.push_back(sigma / std::abs(p.value[i]));
    f.max_sigma = std::max(f.max_sigma, sigma);
    if (p.determined[i]) largest_determined = std::max(largest_determined, sigma);
    else ++f.undetermined;
  }
  std::vector<double> abs_z;
  for (std::size_t i = 0; i < p.truth.size(); ++i) abs_z.push_back(std::abs(p.value[i] - p.truth[i]) / p.sigma[i]);
  f.within_three_sigma = p.truth.empty() ? 0 : static_cast<double>(std::count_if(abs_z.begin(), abs_z.end(), [](double z) { return z <= 3; })) / static_cast<double>(p.truth.size());
  f.z_spread = median(abs_z) / 0.6745;
  std::vector<double> rel_error;
  for (std::size_t i = 0; i < p.truth.size(); ++i) rel_error.push_back(std::abs(p.value[i] - p.truth[i]) / std::abs(p.truth[i]));
  f.median_rel_error = median(rel_error);
  f.within_two_sigma = p.truth.empty() ? 0 : static_cast<double>(within) / static_cast<double>(p.truth.size());
  f.median_rel_sigma = median(rel);
  f.max_over_median = largest_determined / median(p.sigma);
  return f;
}

// Simulates the scan with the reference integrator (steady tapping before the first pixel, the
// first window's start unknown, every later one continued) and inverts it window by window.
ScanFigures run_scan(const ScanSpec& spec) {
  using clock = std::chrono::steady_clock;
  const ModalModel modal(testing::paper_probe());
  const double drive_hz = modal.modes()[0].frequency_hz, drive_m = 0.6e-9;  // ~60 nm free amplitude, as the demo
  const int n = spec.samples_per_window, rows = (spec.pixels + spec.pixels_per_row - 1) / spec.pixels_per_row;
  ParameterSpace space(ForceModelKind::spring);
  space.make_unknown("k_n_per_m", 0.5, 20.0);
  space.make_unknown("h_m", 10e-9, 70e-9);
  auto backend = make_cpu_backend(2);
  InversionOptions options = testing::unbudgeted_options();
  options.parameter_drift_rel = spec.drift;
  Inverter inv(ProbeModel{"p", modal, space, options}, *backend);
  std::mt19937_64 rng(20261128);
  std::normal_distribution<double> noise(0.0, spec.noise_m);

  // Run in from the linear steady state for six decay times of mode 1, as `tipforce simulate` does.
  const Truth first = cell_truth(0, spec.pixels_per_row, rows, spec.substrate_h_m);
  const double tau_s = 2 * modal.modes()[0].quality_factor / modal.modes()[0].omega_rad_per_s;
  const int lead = static_cast<int>(6 * tau_s / spec.sample_period_s);
  Window lead_in = testing::sine_window(lead, drive_m, drive_hz, spec.sample_period_s, -lead * spec.sample_period_s);
  ModalState state = linear_steady_state(modal, drive_m, drive_hz, 0.0, lead_in.t0_s);
  state = reference_simulate(modal, ForceModelKind::spring, lead_in,
                             testing::full_params({first.k_n_per_m, first.h_m}, lead_in), state)
              .end_state;

  ScanFigures out;
  ParameterSamples k, h, cold_k, cold_h;
  for (int px = 0; px < spec.pixels; ++px) {
    const Truth t = cell_truth(px, spec.pixels_per_row, rows, spec.substrate_h_m);
    Window w = testing::sine_window(n, drive_m, drive_hz, spec.sample_period_s, px * n * spec.sample_period_s);
    const auto t0 = clock::now();
    const ReferenceResult ref =
        reference_simulate(modal, ForceModelKind::spring, w, testing::full_params({t.k_n_per_m, t.h_m}, w), state);
    const auto t1 = clock::now();
    state = ref.end_state;
    for (int i = 0; i < n; ++i) w.deflection_m[static_cast<std::size_t>(i)] = ref.signal[static_cast<std::size_t>(i)] + noise(rng);
    w.initial = px == 0 ? InitialState::unknown : InitialState::continued;
    const Estimate e = inv.invert(w);
    if (spec.cold_every > 0 && px % spec.cold_every == spec.cold_every / 2) {
      Inverter cold(ProbeModel{"p", modal, space, testing::unbudgeted_options()}, *backend);
      Window unknown = w;
      unknown.initial = InitialState::unknown;
      const Estimate c = cold.invert(unknown);
      ++out.cold_windows;
      if (c.status != EstimateStatus::ok || c.values.size() != 2u) {
        ++out.cold_not_ok;
      } else {
        cold_k.add(t.k_n_per_m, c, 0);
        cold_h.add(t.h_m, c, 1);
      }
      if (std::getenv("TIPFORCE_TEST_VERBOSE") && c.values.size() == 2u)
        std::printf("cold px %d k %.3f est %.3f sd %.3g | h %.3e est %.3e sd %.3g | misfit %.3e st %d solves %d %s\n", px,
                    t.k_n_per_m, c.values[0], c.sigma[0], t.h_m, c.values[1], c.sigma[1], c.misfit,
                    static_cast<int>(c.status), c.forward_solves, c.message.c_str());
    }
    out.seconds_simulate += std::chrono::duration<double>(t1 - t0).count();
    out.seconds_invert += std::chrono::duration<double>(clock::now() - t1).count();
    ++out.windows;
    if (e.status == EstimateStatus::rejected || e.values.size() != 2u) continue;
    ++out.answered;
    // A window that is not OK says so (e.g. a contact too light to determine k), and its sigma
    // is no claim; the figures are over the windows reported as OK.
    if (e.status != EstimateStatus::ok) {
      ++out.not_ok;
      continue;
    }
    k.add(t.k_n_per_m, e, 0);
    h.add(t.h_m, e, 1);
    if (std::getenv("TIPFORCE_TEST_VERBOSE"))
      std::printf("px %d k %.3f est %.3f sd %.3g | h %.3e est %.3e sd %.3g | misfit %.3e st %d solves %d us %.0f %s\n", px, t.k_n_per_m,
                  e.values[0], e.sigma[0], t.h_m, e.values[1], e.sigma[1], e.misfit, static_cast<int>(e.status),
                  e.forward_solves, 1e6 * e.solve_seconds, e.message.c_str());
  }
  out.k = figures(k);
  out.h = figures(h);
  out.cold_k = figures(cold_k);
  out.cold_h = figures(cold_h);
  std::printf("%s: %d windows, %d answered, %d not ok; simulate %.1f s, invert %.1f s\n", spec.label, out.windows,
              out.answered, out.not_ok, out.seconds_simulate, out.seconds_invert);
  for (const auto& [name, f] : {std::pair{"k", out.k}, std::pair{"h", out.h}})
    std::printf("  %s: within 2 sigma %.1f %% (3 sigma %.1f %%; errors' robust spread %.2f sigma), median sigma/value "
                "%.2f %%, median error %.2f %%, max sigma / median sigma %.3g (determined windows), largest sigma %.3g, "
                "%d windows undetermined\n",
                name, 100 * f.within_two_sigma, 100 * f.within_three_sigma, f.z_spread, 100 * f.median_rel_sigma,
                100 * f.median_rel_error, f.max_over_median, f.max_sigma, f.undetermined);
  if (out.cold_windows > 0) {
    std::printf("  cold starts: %d windows, %d not ok\n", out.cold_windows, out.cold_not_ok);
    for (const auto& [name, f] : {std::pair{"k", out.cold_k}, std::pair{"h", out.cold_h}})
      std::printf("  cold %s: within 2 sigma %.1f %%, median sigma/value %.2f %%, largest sigma %.3g\n", name,
                  100 * f.within_two_sigma, 100 * f.median_rel_sigma, f.max_sigma);
  }
  for (const auto& [name, f] : {std::pair{"k", out.k}, std::pair{"h", out.h}}) {
    ::testing::Test::RecordProperty(std::string("within_2sigma_") + name, std::to_string(f.within_two_sigma));
    ::testing::Test::RecordProperty(std::string("median_rel_sigma_") + name, std::to_string(f.median_rel_sigma));
    ::testing::Test::RecordProperty(std::string("max_over_median_sigma_") + name, std::to_string(f.max_over_median));
  }
  return out;
}

// bounds_spread: (high - low) / sqrt(12) per unknown, the spread of the bounds themselves.
void expect_honest(const ScanFigures& s, double k_bounds_spread, double h_bounds_spread) {
  EXPECT_EQ(s.answered, s.windows);
  EXPECT_LE(s.not_ok, s.windows / 20) << "more than 5 % of the windows not OK";
  for (const auto& [name, f, spread] : {std::tuple{"k", s.k, k_bounds_spread}, std::tuple{"h", s.h, h_bounds_spread}}) {
    EXPECT_GE(f.within_two_sigma, 0.90) << name << ": the truth within 2 sigma too rarely (sigma too small)";
    EXPECT_LE(f.median_rel_sigma, 0.10) << name << ": median sigma / value above 10 % (sigma inflated or undetermined)";
    EXPECT_LE(f.max_over_median, 20.0) << name << ": the largest sigma is far above the median (does it compound?)";
    // Bounded by construction: no window claims to know less than the bounds already say.
    EXPECT_LE(f.max_sigma, 1.0001 * spread) << name;
    EXPECT_LE(f.undetermined, s.windows / 20) << name << ": more than 5 % of the windows do not determine it";
  }
}

const double kBoundsSpreadK = 19.5 / std::sqrt(12.0), kBoundsSpreadH = 60e-9 / std::sqrt(12.0);

// The scan pooled along the line as the demo pools it (drift per pixel 5 % in k, 1 % in h), held
// to expect_honest and to pooled sigmas that are neither inflated (the errors' robust spread at
// least 0.6 sigma: too wide ones would pass the coverage by being useless) nor too small (at most
// 1.2 sigma, and the tails: a change of the sample that the gate lets through pulls its pixel's
// answer towards the previous one's).
ScanFigures expect_honest_pooled_as_the_demo(ScanSpec spec, double min_within_three_sigma) {
  spec.drift = {{"k_n_per_m", 0.05}, {"h_m", 0.01}};
  const ScanFigures s = run_scan(spec);
  expect_honest(s, kBoundsSpreadK, kBoundsSpreadH);
  for (const auto& [name, f] : {std::pair{"k", s.k}, std::pair{"h", s.h}}) {
    EXPECT_GE(f.within_three_sigma, min_within_three_sigma) << name;
    EXPECT_GE(f.z_spread, 0.6) << name << ": pooled sigmas inflated";
    EXPECT_LE(f.z_spread, 1.2) << name << ": pooled sigmas too small";
  }
  return s;
}

// 5 MHz sampling, 400-sample windows (about two drive periods): the demo's acquisition, 16 rows
// of 64 pixels. The substrate sits at 35 nm (the tip's free amplitude is ~60 nm: firm tapping).
// At the demo's 45 nm the contact is so light that two periods determine the substrate's k to
// ~10.4 % only (median sigma / value, measured with everything else as here): a limit of the
// data, not of the method, and too close to the 10 % line for a test.
TEST(Honesty, ThousandContinuedShortWindowsAt5MHz) {
  const ScanFigures s = run_scan({"5 MHz, 400 samples", 400, 2e-7, 1024, 64, 0.1e-9, 35e-9, 16});
  expect_honest(s, kBoundsSpreadK, kBoundsSpreadH);
  // Every 16th window also inverted on its own with its start unknown (64 cold starts): where such
  // a window reports OK, its sigma must be as honest. Two drive periods with the start free also
  // admit a wrong basin in which the tip never touches (h above its reach; k then undetermined):
  // it is reported NOT_CONVERGED: 6 of the 64 cold starts with the swarm alone, 3 since the
  // physics start of issue 9 (InversionOptions::cold_physics_*). The bound here only keeps it from
  // growing unseen.
  EXPECT_GE(s.cold_windows, 64);
  EXPECT_LE(s.cold_not_ok, s.cold_windows / 8) << "cold starts not OK";
  for (const auto& [name, f] : {std::pair{"k", s.cold_k}, std::pair{"h", s.cold_h}})
    EXPECT_GE(f.within_two_sigma, 0.90) << "cold starts, " << name << ": the truth within 2 sigma too rarely";
}

// Pooling along the line (InversionOptions::parameter_drift_rel) at the demo's separation of 45 nm,
// where two drive periods alone determine the substrate's k to 13-14 % (the Cramer-Rao bound with
// the start known is 12.9 %: efficiency_test), so that the demo's scan cannot meet the 10 % line
// pixel by pixel (13.2 %; this scan's softer dome brings its median to 10.6 %). With
// the previous pixel's parameters as a prior (drift per pixel 5 % in k, 1 % in h, as the demo),
// sigma must fall below 10 % and stay true: the truth within 2 sigma for >= 90 %, within 3 sigma
// for >= 98 % (a change of the sample that the gate lets through pulls its pixel's answer towards
// the previous one's), and the errors' robust spread 0.6-1.2 sigma (pooled sigmas too wide would
// pass the coverage by being useless; a drift wider than the sample's own makes them somewhat
// conservative: 0.85 on the demo).
TEST(Honesty, PooledAlongTheLineAt5MHzWhereOneWindowCannotDetermineK) {
  const ScanFigures s =
      expect_honest_pooled_as_the_demo({"5 MHz, 400 samples, 45 nm, pooled", 400, 2e-7, 1024, 64, 0.1e-9, 45e-9}, 0.98);
  // The same data pixel by pixel: the pooled estimates must be closer to the truth, not only
  // surer (median sigma_k/k and median error 10.6 % and 6.4 % pixel by pixel, 7.0 % and 3.5 %
  // pooled; windows that leave an unknown undetermined 62 and 10).
  const ScanFigures alone = run_scan({"5 MHz, 400 samples, 45 nm, pixel by pixel", 400, 2e-7, 1024, 64, 0.1e-9, 45e-9});
  EXPECT_LT(s.k.median_rel_sigma, 0.75 * alone.k.median_rel_sigma);
  EXPECT_LT(s.k.median_rel_error, 0.9 * alone.k.median_rel_error);
}

// 10 MHz sampling (the paper's rate), 800-sample windows (two drive periods), pooled as the demo,
// at the demo's separation of 45 nm, where the substrate's contact is so light that its stiffness
// trades against its depth along a long, curved valley. At the cell's rim a window's own answer
// then lay at the valley's soft end (k at its lower bound, 0.5 N/m, against 12) and the pooling's
// linear gate misjudged it both ways: it left such answers unpooled and wrong, and let a Kalman
// point through that lay off the valley (the pooled polish ended at 3 x the window's own misfit,
// k 1.0 +- 0.2 against 12, the next five pixels following it). Largest / median sigma of h 63.5,
// 33 windows (of 1020 OK) beyond 3 sigma in k or h. With the innovation measured on the model as well
// (InversionOptions::pool_valley_chi2) and a tracked answer at a bound searched further: 15.2,
// within 3 sigma 98.7 % (k) and 98.4 % (h), 15 windows beyond.
TEST(Honesty, PooledAt10MHzAcrossLightContacts) {
  expect_honest_pooled_as_the_demo({"10 MHz, 800 samples, 45 nm, pooled", 800, 1e-7, 1024, 64, 0.1e-9, 45e-9}, 0.97);
}

// 1 MHz sampling at 2 kHz per pixel (PeakForce-QNM-like rates): 500-sample windows, 12.7 drive
// periods. Measured (2026-12-07, 512 windows): within 2 sigma 95.1 % (k), 95.5 % (h), sigma/value
// 7.0 % and 0.15 %. Longer windows at the faster rates (2500 samples at 5 MHz, 5000 at 10 MHz:
// 2 kHz per pixel) gave within 2 sigma 96.3-97.1 % (k and h), k's sigma/value 3.2 and 2.3 %, and
// pooled 97.3-97.7 % (not run here: 30 s more).
TEST(Honesty, ContinuedWindowsAt1MHzFor2kHzPixels) {
  expect_honest(run_scan({"1 MHz, 500 samples", 500, 1e-6, 512, 64, 0.1e-9, 35e-9}), kBoundsSpreadK, kBoundsSpreadH);
}

// 1 MHz sampling, 1250-sample windows (about 32 drive periods; a contact lasts a few samples).
// With the forward solver within 1e-4 at 1e-6 s (issue 8) the truth was within 2 sigma for
// 95.4 % (k) and 94.3 % (h) of the windows, but the largest / median sigma of h was 29.7 against
// the limit of 20: at the rim of the cell the warm search of a continued window missed the
// substrate's k (0.5 for 12 N/m, misfit 35 times the noise's) and the next windows followed it.
// The start-conflict test now finds those windows and searches them from their own data (issue 9):
// 97.1 % and 96.3 %, largest / median sigma of h 3.2. About 35 s on an idle 2-core machine
// (reference data 25 s), up to a few minutes on a loaded one.
TEST(Honesty, ThousandContinuedLongWindowsAt1MHz) {
  expect_honest(run_scan({"1 MHz, 1250 samples", 1250, 1e-6, 1024, 64, 0.1e-9, 35e-9}), kBoundsSpreadK, kBoundsSpreadH);
}

// Every force model, not the spring alone: a continued scan of 256 windows (4 rows of 64) over a
// sample whose stiffness-like parameter varies smoothly by +-40 % with a 1.5 x step every 16
// pixels and whose surface moves by +-2 nm, from the reference integrator, 0.1 nm noise. The
// unknowns are what a user fits: the stiffness-like parameter and h, with Kelvin-Voigt's damping
// and viscous DMT's viscosity as a third; a tip's radius, the Hamaker constant and a0 fixed.
struct ModelCase {
  std::string label;
  ForceModelKind model;
  std::vector<double> truth;  // the model's parameters (SPEC section 1 order) at the scan's mean
  std::vector<std::tuple<std::string, double, double>> unknowns;  // name, low, high
  int h_index, stiffness_index;
  double sample_period_s;
  int samples_per_window;
  double max_median_rel_sigma;  // the size check (see the instantiation)
  // Pooling along the line: every unknown's drift per pixel (InversionOptions::parameter_drift_rel),
  // h's a fifth of it; 0: none (pixel by pixel).
  double pool_drift = 0;
  // gtest prints a parameter by its bytes unless told; ctest's log then shows 120 of them.
  friend void PrintTo(const ModelCase& c, std::ostream* os) { *os << c.label; }
};

struct UnknownFigures {
  std::string name;
  ParameterFigures f;
  double bounds_spread;
};

struct ModelScan {
  int windows = 0, not_ok = 0, cold_windows = 0, cold_not_ok = 0;
  std::vector<UnknownFigures> figures, cold_figures;
};

ModelScan run_model_scan(const ModelCase& c) {
  const ModalModel modal(testing::paper_probe());
  const double drive_hz = modal.modes()[0].frequency_hz, drive_m = 0.6e-9;
  const double dt = c.sample_period_s;
  const int n = c.samples_per_window, pixels = 256, cold_every = 8;
  const auto names = force_model_parameters(c.model);
  ParameterSpace space(c.model);
  // The unknowns in the space's order (the model's), each with its index among the parameters.
  std::vector<int> unknown_index;
  std::vector<std::tuple<std::string, double, double>> unknowns;
  for (std::size_t j = 0; j < names.size(); ++j) {
    const auto u = std::find_if(c.unknowns.begin(), c.unknowns.end(), [&](const auto& t) { return std::get<0>(t) == names[j]; });
    if (u == c.unknowns.end()) {
      space.fix(names[j], c.truth[j]);
    } else {
      space.make_unknown(names[j], std::get<1>(*u), std::get<2>(*u));
      unknown_index.push_back(static_cast<int>(j));
      unknowns.push_back(*u);
    }
  }
  const int m = static_cast<int>(unknown_index.size());
  auto truth = [&](int px) {
    std::vector<double> p = c.truth;
    const double x = px % 64, y = px / 64;
    p[static_cast<std::size_t>(c.stiffness_index)] *= 1.0 + 0.4 * std::sin(0.15 * x + 0.5 * y) + ((px % 64) / 16 % 2 ? 0.5 : 0.0);
    p[static_cast<std::size_t>(c.h_index)] += 2e-9 * std::cos(0.1 * x + 0.3 * y);
    return p;
  };
  auto backend = make_cpu_backend(2);
  InversionOptions options = testing::unbudgeted_options();
  if (c.pool_drift > 0)
    for (const auto& [name, low, high] : unknowns) options.parameter_drift_rel[name] = name == "h_m" ? c.pool_drift / 5 : c.pool_drift;
  Inverter inv(ProbeModel{"p", modal, space, options}, *backend);
  std::mt19937_64 rng(20261204);
  std::normal_distribution<double> noise(0.0, 0.1e-9);
  const double tau_s = 2 * modal.modes()[0].quality_factor / modal.modes()[0].omega_rad_per_s;
  const int lead = static_cast<int>(6 * tau_s / dt);
  const Window lead_in = testing::sine_window(lead, drive_m, drive_hz, dt, -lead * dt);
  ModalState state = reference_simulate(modal, c.model, lead_in, testing::full_params(truth(0), lead_in),
                                        linear_steady_state(modal, drive_m, drive_hz, 0.0, lead_in.t0_s))
                         .end_state;
  std::vector<ParameterSamples> samples(static_cast<std::size_t>(m)), cold(static_cast<std::size_t>(m));
  ModelScan out;
  for (int px = 0; px < pixels; ++px) {
    const std::vector<double> t = truth(px);
    Window w = testing::sine_window(n, drive_m, drive_hz, dt, px * n * dt);
    const ReferenceResult ref = reference_simulate(modal, c.model, w, testing::full_params(t, w), state);
    state = ref.end_state;
    for (int i = 0; i < n; ++i) w.deflection_m[static_cast<std::size_t>(i)] = ref.signal[static_cast<std::size_t>(i)] + noise(rng);
    w.initial = px == 0 ? InitialState::unknown : InitialState::continued;
    const Estimate e = inv.invert(w);
    ++out.windows;
    if (std::getenv("TIPFORCE_TEST_VERBOSE") && static_cast<int>(e.values.size()) == m)
      std::printf("px %d %s %.4g est %.4g sd %.3g z %.2f | st %d %s\n", px, std::get<0>(unknowns[0]).c_str(),
                  t[static_cast<std::size_t>(unknown_index[0])], e.values[0], e.sigma[0],
                  (e.values[0] - t[static_cast<std::size_t>(unknown_index[0])]) / e.sigma[0], static_cast<int>(e.status),
                  e.message.c_str());
    if (e.status != EstimateStatus::ok || static_cast<int>(e.values.size()) != m) {
      ++out.not_ok;
    } else {
      for (int j = 0; j < m; ++j) samples[static_cast<std::size_t>(j)].add(t[static_cast<std::size_t>(unknown_index[j])], e, j);
    }
    if (px % cold_every != cold_every / 2) continue;
    Inverter alone(ProbeModel{"p", modal, space, testing::unbudgeted_options()}, *backend);
    w.initial = InitialState::unknown;
    const Estimate a = alone.invert(w);
    ++out.cold_windows;
    if (a.status != EstimateStatus::ok || static_cast<int>(a.values.size()) != m) {
      ++out.cold_not_ok;
      continue;
    }
    for (int j = 0; j < m; ++j) cold[static_cast<std::size_t>(j)].add(t[static_cast<std::size_t>(unknown_index[j])], a, j);
  }
  std::printf("%s: %d windows, %d not ok; %d cold starts, %d not ok\n", c.label.c_str(), out.windows, out.not_ok,
              out.cold_windows, out.cold_not_ok);
  for (int j = 0; j < m; ++j) {
    const auto& [name, low, high] = unknowns[static_cast<std::size_t>(j)];
    out.figures.push_back({name, figures(samples[static_cast<std::size_t>(j)]), (high - low) / std::sqrt(12.0)});
    out.cold_figures.push_back({name, figures(cold[static_cast<std::size_t>(j)]), (high - low) / std::sqrt(12.0)});
    const ParameterFigures& f = out.figures.back().f;
    const ParameterFigures& g = out.cold_figures.back().f;
    std::printf("  %-11s within 2 sigma %.1f %% (3 sigma %.1f %%, errors' robust spread %.2f sigma), median sigma/value "
                "%.2f %%, median error %.2f %%, max sigma / median sigma %.3g; cold starts: within 2 sigma %.1f %%, "
                "median sigma/value %.2f %%\n",
                name.c_str(), 100 * f.within_two_sigma, 100 * f.within_three_sigma, f.z_spread, 100 * f.median_rel_sigma,
                100 * f.median_rel_error, f.max_over_median, 100 * g.within_two_sigma, 100 * g.median_rel_sigma);
  }
  return out;
}

class HonestyEveryModel : public ::testing::TestWithParam<ModelCase> {};

TEST_P(HonestyEveryModel, ContinuedScanAndColdStarts) {
  const ModelCase& c = GetParam();
  const ModelScan s = run_model_scan(c);
  EXPECT_LE(s.not_ok, s.windows / 20) << "more than 5 % of the windows not OK";
  for (const UnknownFigures& u : s.figures) {
    EXPECT_GE(u.f.within_two_sigma, 0.90) << u.name << ": the truth within 2 sigma too rarely (sigma too small)";
    EXPECT_LE(u.f.median_rel_sigma, c.max_median_rel_sigma) << u.name << ": median sigma / value (sigma inflated?)";
    EXPECT_LE(u.f.max_over_median, 20.0) << u.name << ": the largest sigma is far above the median (does it compound?)";
    EXPECT_LE(u.f.max_sigma, 1.0001 * u.bounds_spread) << u.name;
    EXPECT_LE(u.f.undetermined, s.windows / 20) << u.name << ": more than 5 % of the windows do not determine it";
    // Pooled sigmas too wide would pass the coverage by being useless, too narrow ones at the
    // sample's changes would show in the tails (measured: spread 0.78-1.01, 3 sigma 98.4-100 %).
    if (c.pool_drift > 0) {
      EXPECT_GE(u.f.z_spread, 0.6) << u.name << ": pooled sigmas inflated";
      EXPECT_LE(u.f.z_spread, 1.25) << u.name << ": pooled sigmas too small";
      EXPECT_GE(u.f.within_three_sigma, 0.97) << u.name;
    }
  }
  // Cold starts: 32 windows inverted alone, start unknown. 85 %: 32 windows' coverage scatters by
  // ~4 % about its 95 %. With three unknowns the swarm alone (before the physics grid took a third
  // unknown, InversionOptions::cold_physics_grid_further) left Kelvin-Voigt and viscous DMT at
  // 81 % at 1 MHz, 6 of 32 in another basin reported OK.
  EXPECT_LE(s.cold_not_ok, s.cold_windows / 8) << "cold starts not OK";
  for (const UnknownFigures& u : s.cold_figures)
    EXPECT_GE(u.f.within_two_sigma, 0.85) << "cold starts, " << u.name << ": the truth within 2 sigma too rarely";
}

using Bounds = std::tuple<std::string, double, double>;
const Bounds kStiffness{"k_n_per_m", 0.5, 20.0}, kModulus{"e_star_pa", 1e7, 1e11}, kSeparation{"h_m", 10e-9, 70e-9};

std::vector<ModelCase> model_cases() {
  // The size check: at 1 MHz (1250 samples, ~32 drive periods) the 10 %; at 5 MHz (400
  // samples, two periods) a 1 GPa contact through a 10 nm tip is ~8 x as stiff as the lever, where
  // two periods determine the modulus to ~16-19 % (measured; the spring's 12 N/m substrate, as stiff
  // relative to the lever, has a Cramer-Rao bound of 13 % with the start known, efficiency_test).
  // At 10 MHz (800 samples, the paper's rate) the same two periods: 7.3-13.8 % pixel by pixel
  // (measured 2026-12-07; every model within 2 sigma 94.5-98.0 %, pooled 92.6-98.0 %).
  std::vector<ModelCase> cases;
  for (const auto& [rate, dt, n, size] : {std::tuple{"1mhz", 1e-6, 1250, 0.10}, std::tuple{"5mhz", 2e-7, 400, 0.25}, std::tuple{"10mhz", 1e-7, 800, 0.25}}) {
    auto add = [&](const char* model, ForceModelKind kind, std::vector<double> truth, std::vector<Bounds> unknowns, int h,
                   int stiffness) {
      cases.push_back({std::string(model) + "_" + rate, kind, std::move(truth), std::move(unknowns), h, stiffness, dt, n, size});
    };
    add("spring", ForceModelKind::spring, {4.0, 35e-9}, {kStiffness, kSeparation}, 1, 0);
    add("kelvin_voigt", ForceModelKind::kelvin_voigt, {4.0, 5e-6, 35e-9},
        {kStiffness, Bounds{"c_ns_per_m", 0.0, 5e-5}, kSeparation}, 2, 0);
    add("hertz", ForceModelKind::hertz, {1e9, 10e-9, 35e-9}, {kModulus, kSeparation}, 2, 0);
    add("dmt", ForceModelKind::dmt, {1e9, 10e-9, 1e-19, 0.3e-9, 35e-9}, {kModulus, kSeparation}, 4, 0);
    add("dmt_viscous", ForceModelKind::dmt_viscous, {1e9, 10e-9, 1e-19, 0.3e-9, 35e-9, 200.0},
        {kModulus, kSeparation, Bounds{"eta_pa_s", 0.0, 1e4}}, 4, 0);
  }
  // Pooled along the line (at 5 MHz one window alone leaves the stiffness at 10-22 %), with a
  // drift of 10 % per pixel in the stiffness and 2 % in h: this sample's stiffness changes by up to
  // 6 % from one pixel to the next and steps by 1.5 x every 16 pixels. A drift below the sample's
  // own change makes the pooled sigmas too small where it changes: at 5 % the filter lagged the
  // 6 %-per-pixel ramps by up to 4 sigma, and Hertz, DMT and viscous DMT had the truth within
  // 2 sigma for 86-88 % (errors' robust spread 1.4-1.5 sigma); matching the drift to the
  // innovations (covariance matching) did not find the lag in time and was not kept.
  for (std::size_t i = 0, n = cases.size(); i < n; ++i) {
    ModelCase pooled = cases[i];
    pooled.label += "_pooled";
    pooled.pool_drift = 0.1;
    cases.push_back(pooled);
  }
  return cases;
}

INSTANTIATE_TEST_SUITE_P(ForceModels, HonestyEveryModel, ::testing::ValuesIn(model_cases()),
                         [](const ::testing::TestParamInfo<ModelCase>& i) { return i.param.label; });

}  // namespace
}  // namespace tipforce
