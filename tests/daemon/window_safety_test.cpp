// Issue 10, in the window/message layer that tipforced and `tipforce invert` share
// (WindowProcessor): windows absurd for their probe are REJECTED with the reason and leave the
// stream untouched; probe names are bounded and printable; every estimate that is not OK says why.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <optional>
#include <tuple>
#include <chrono>
#include <thread>

#include "testlib.hpp"
#include "tipforce/backend.hpp"
#include "tipforce/window_processor.hpp"

using namespace tfdtest;
using tipforce::deflection_window_t;
using tipforce::force_estimate_t;

namespace {

std::string fmt_param(const std::string& name, double a, double b) {
  char buf[160];
  std::snprintf(buf, sizeof(buf), " %.17g vs %.17g", a, b);
  return name + buf;
}

struct Fixture {
  tipforce::Config config;
  tipforce::BackendChoice backend = tipforce::make_backend("cpu");
  std::unique_ptr<tipforce::lcmio::WindowProcessor> processor;
  explicit Fixture(const std::string& extra_daemon = "") {
    config = tipforce::parse_config(test_config(64, 0.25, 3, extra_daemon), "test.toml");
    processor = std::make_unique<tipforce::lcmio::WindowProcessor>(config, *backend.backend);
  }
  tipforce::lcmio::ProcessedWindow process(const std::vector<std::uint8_t>& bytes) {
    return processor->process(bytes.data(), bytes.size(), 0);
  }
  tipforce::lcmio::ProcessedWindow process(const deflection_window_t& w) { return process(encode(w)); }
};

void expect_rejected(const tipforce::lcmio::ProcessedWindow& r, const std::string& reason_part,
                     const std::string& what) {
  ASSERT_TRUE(r.estimate) << what;
  EXPECT_EQ(r.estimate->status, force_estimate_t::STATUS_REJECTED) << what;
  EXPECT_NE(r.estimate->message.find(reason_part), std::string::npos) << what << ": " << r.estimate->message;
  std::printf("%-34s REJECTED: %s\n", what.c_str(), r.estimate->message.c_str());
}

}  // namespace

TEST(WindowSafety, WindowsAbsurdForTheProbeAreRejectedWithTheReason) {
  Fixture f;
  struct Case {
    std::string what, reason;
    std::function<void(deflection_window_t&)> change;
  };
  const std::vector<Case> cases = {
      {"drive amplitude 1e30 m", "drive_amplitude_m 1e+30 m is not below the cantilever's length",
       [](auto& w) { w.drive_amplitude_m = 1e30; }},
      {"drive amplitude 1 mm (> L)", "not below the cantilever's length", [](auto& w) { w.drive_amplitude_m = 1e-3; }},
      {"drive frequency 1e12 Hz", "drive_frequency_hz 1e+12 Hz is not below the Nyquist frequency",
       [](auto& w) { w.drive_frequency_hz = 1e12; }},
      {"drive frequency 100 Hz", "outside", [](auto& w) { w.drive_frequency_hz = 100; }},
      {"drive frequency 0 Hz", "outside", [](auto& w) { w.drive_frequency_hz = 0; }},
      {"chirp sweeping to 1 GHz", "the chirp's instantaneous frequency",
       [](auto& w) {
         w.drive_kind = deflection_window_t::DRIVE_CHIRP;
         w.t0_s = 1.0;
         w.drive_chirp_hz_per_s = 5e8;
       }},
      {"sample period 1e-15 s", "below 1e-10 s", [](auto& w) { w.sample_period_s = 1e-15; }},
      {"sample period 1 ms (mode 1 aliased)", "cannot resolve the probe's first mode",
       [](auto& w) { w.sample_period_s = 1e-3; }},
      {"t0 of 1e300 s", "t0_s 1e+300 s is beyond", [](auto& w) { w.t0_s = 1e300; }},
      {"drive phase 1e20 rad", "drive_phase_rad", [](auto& w) { w.drive_phase_rad = 1e20; }},
      {"sampled base of 1 m", "base sample 0 (1 m) is not below",
       [](auto& w) {
         w.drive_kind = deflection_window_t::DRIVE_SAMPLED;
         w.n_base_samples = w.n_samples;
         w.base_m.assign(static_cast<std::size_t>(w.n_samples), 1.0f);
       }},
  };
  for (const Case& c : cases) {
    deflection_window_t w = small_window("tip", 7);
    c.change(w);
    expect_rejected(f.process(w), c.reason, c.what);
  }
  // And a sane window is still answered.
  auto ok = f.process(small_window("tip", 8));
  ASSERT_TRUE(ok.estimate);
  EXPECT_NE(ok.estimate->status, force_estimate_t::STATUS_REJECTED) << ok.estimate->message;
}

TEST(WindowSafety, ShortWindowsAreRejectedWithAMessage) {
  Fixture f;
  for (int n : {1, 2, 3, 7}) {
    auto r = f.process(small_window("tip", n, n));
    expect_rejected(r, "samples; at least 8 are needed", std::to_string(n) + "-sample window");
    EXPECT_FALSE(r.estimate->message.empty());
  }
}

TEST(WindowSafety, SamplesPerWindowAreCappedByTheConfig) {
  Fixture f("max_window_samples = 1000");
  expect_rejected(f.process(small_window("tip", 1, 1001)), "more than the limit of 1000 (daemon.max_window_samples)",
                  "1001 samples, limit 1000");
  auto ok = f.process(small_window("tip", 2, 1000));
  ASSERT_TRUE(ok.estimate);
  EXPECT_NE(ok.estimate->status, force_estimate_t::STATUS_REJECTED) << ok.estimate->message;
}

TEST(WindowSafety, ProbeNamesAreBoundedPrintableAndWithoutNul) {
  Fixture f;
  // 1 MB name: rejected, and what comes back (estimate and log) is bounded.
  auto big = f.process(small_window(std::string(1'000'000, 'a'), 1));
  expect_rejected(big, "probe name is 1000000 bytes, more than 64", "1 MB probe name");
  EXPECT_LT(big.estimate->probe.size(), 100u);
  EXPECT_LT(big.estimate->message.size(), 300u);
  // A newline and an ANSI escape would forge log lines: rejected and escaped.
  auto forged = f.process(small_window("tip\n2026-01-01 [info] all good\x1b[2J", 2));
  expect_rejected(forged, "non-printable byte at 3", "probe name with newline and ANSI");
  for (const std::string* s : {&forged.estimate->probe, &forged.estimate->message, &forged.reason})
    for (char c : *s) EXPECT_TRUE(c >= 0x20 && c <= 0x7e) << "unescaped byte " << int(c) << " in " << *s;
  EXPECT_NE(forged.estimate->probe.find("tip\\x0a2026"), std::string::npos) << forged.estimate->probe;
  // "tip\0x": LCM's decoder would read "tip". Built by hand, since LCM's encoder stops at the NUL.
  auto bytes = encode(small_window("tip?x", 3));
  const std::size_t name_at = 8 + 8 + 4;  // fingerprint, utime, string length
  ASSERT_EQ(bytes[name_at + 3], '?');
  bytes[name_at + 3] = 0;
  auto nul = f.process(bytes);
  expect_rejected(nul, "probe name has a NUL byte at 3", "probe name \"tip\\0x\"");
  EXPECT_EQ(nul.estimate->probe, "tip\\x00x");
  // 64 printable characters are fine (an unknown probe, then).
  expect_rejected(f.process(small_window(std::string(64, 'p'), 4)), "unknown probe", "64-character name");
}

// Issue 10's acceptance, as written: one absurd window in a 4096-window continued scan changes
// nothing beyond the next window. It is compared with the same scan without that window (never
// sent, as if lost on the way): a REJECTED window leaves the probe's stream as it was, so every
// other estimate must be the one the stream gets without it (equal to 1e-12 relative; in practice
// bit for bit). The comparison could fail: on this scan what went before matters (the chain of
// warm starts and the inverter's random stream; checked below with the window present and good),
// and the issue found the next 246 windows spoiled.
//
// 200-sample windows (4 drive periods) and a one-thread backend per run keep the four runs (two
// spoiled, one without the window, a short one with it) near a minute on a loaded 2-core machine;
// they run side by side. About 40 % of these short windows are NOT_CONVERGED (k and h trade off
// over 4 periods), which the comparison does not care about: it compares whatever comes out.
TEST(Poisoning, OneAbsurdWindowInA4096WindowScanChangesNothingBeyondTheNextWindow) {
  const int n = 4096, bad = 100, sensitivity_span = 200;
  const tipforce::Config config = tipforce::parse_config(test_config(64, 0.25, 3), "test.toml");
  ScanOptions so;
  so.windows = n;
  so.samples = 200;
  const std::vector<Event> scan = make_scan(config, so);
  // Answers windows [0, last] of the scan, window `bad` changed by `spoil` or, without one, not
  // sent; nullopt for a window not sent.
  using Spoil = std::function<void(deflection_window_t&)>;
  using Estimates = std::vector<std::optional<force_estimate_t>>;
  auto run = [&](const Spoil& spoil, bool send_bad, int last) {
    auto backend = tipforce::make_backend("cpu", 1);
    tipforce::lcmio::WindowProcessor processor(config, *backend.backend);
    Estimates out(static_cast<std::size_t>(n));
    for (int i = 0; i <= last; ++i) {
      std::vector<std::uint8_t> bytes = scan[static_cast<std::size_t>(i)].data;
      if (i == bad) {
        if (!send_bad) continue;
        if (spoil) {
          auto w = decode<deflection_window_t>(scan[static_cast<std::size_t>(i)]);
          spoil(*w);
          bytes = encode(*w);
        }
      }
      out[static_cast<std::size_t>(i)] = processor.process(bytes.data(), bytes.size(), 0).estimate;
    }
    return out;
  };
  const std::vector<std::pair<std::string, Spoil>> spoils = {
      {"drive_amplitude_m = 1e30", [](deflection_window_t& w) { w.drive_amplitude_m = 1e30; }},
      {"drive_frequency_hz = 1e12", [](deflection_window_t& w) { w.drive_frequency_hz = 1e12; }}};
  const auto t0 = std::chrono::steady_clock::now();
  Estimates without, with_good;
  std::vector<Estimates> spoiled(spoils.size());
  {
    std::vector<std::thread> runs;
    runs.emplace_back([&] { without = run(nullptr, false, n - 1); });
    runs.emplace_back([&] { with_good = run(nullptr, true, bad + sensitivity_span); });
    for (std::size_t s = 0; s < spoils.size(); ++s)
      runs.emplace_back([&, s] { spoiled[s] = run(spoils[s].second, true, n - 1); });
    for (auto& t : runs) t.join();
  }
  std::printf("%d-window scan of %d-sample windows, 4 runs in %.1f s\n", n, so.samples,
              std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
  // Everything an estimate says about its window, but when it was received and published.
  auto difference = [](const force_estimate_t& a, const force_estimate_t& b) -> std::string {
    if (a.status != b.status) return "status " + std::to_string(a.status) + " vs " + std::to_string(b.status);
    if (a.message != b.message) return "message '" + a.message + "' vs '" + b.message + "'";
    if (a.param_names != b.param_names) return "parameter names";
    auto close = [](double x, double y) {
      return x == y || (std::isnan(x) && std::isnan(y)) ||
             std::abs(x - y) <= 1e-12 * std::max(std::abs(x), std::abs(y));
    };
    for (std::size_t k = 0; k < a.params.size(); ++k) {
      if (!close(a.params[k], b.params[k]))
        return fmt_param(a.param_names[k], a.params[k], b.params[k]);
      if (!close(a.param_sigma[k], b.param_sigma[k]))
        return fmt_param("sigma of " + a.param_names[k], a.param_sigma[k], b.param_sigma[k]);
    }
    for (auto [x, y, what] : {std::tuple{a.misfit, b.misfit, "misfit"}, {a.peak_force_n, b.peak_force_n, "peak force"},
                              {a.mean_force_n, b.mean_force_n, "mean force"},
                              {a.max_indentation_m, b.max_indentation_m, "indentation"},
                              {a.dissipated_energy_j, b.dissipated_energy_j, "dissipation"}})
      if (!close(x, y)) return fmt_param(what, x, y);
    if (a.iterations != b.iterations || a.forward_solves != b.forward_solves) return "iterations or forward solves";
    return {};
  };

  int ok = 0, not_converged = 0;
  for (const auto& e : without)
    if (e) ++(e->status == force_estimate_t::STATUS_OK ? ok : not_converged);
  int sensitive = 0;
  for (int i = bad + 1; i <= bad + sensitivity_span; ++i)
    sensitive += !difference(*with_good[static_cast<std::size_t>(i)], *without[static_cast<std::size_t>(i)]).empty();
  std::printf("without the window: %d OK, %d NOT_CONVERGED; with it present and good, %d of the next %d estimates "
              "differ from those without it\n",
              ok, not_converged, sensitive, sensitivity_span);
  EXPECT_GT(sensitive, 0) << "nothing carries from window to window on this scan: the comparison could not fail";

  for (std::size_t s = 0; s < spoils.size(); ++s) {
    const std::string& what = spoils[s].first;
    const Estimates& got = spoiled[s];
    ASSERT_TRUE(got[bad]);
    EXPECT_EQ(got[bad]->status, force_estimate_t::STATUS_REJECTED) << what;
    int compared = 0, differing = 0;
    for (int i = 0; i < n; ++i) {
      if (i == bad) continue;
      const std::string d = difference(*without[static_cast<std::size_t>(i)], *got[static_cast<std::size_t>(i)]);
      ++compared;
      // The acceptance allows the next window to differ; here it does not either.
      if (d.empty()) continue;
      if (++differing <= 5) ADD_FAILURE() << what << ": seq " << i << " differs from the scan without the window: " << d;
    }
    EXPECT_EQ(differing, 0) << what;
    const auto& next = *got[bad + 1];
    std::printf("%s at seq %d: REJECTED (%s). Of the other %d estimates %d differ from the scan without it; the next "
                "window (seq %d) is %s, misfit %.3g\n",
                what.c_str(), bad, got[bad]->message.c_str(), compared, differing, bad + 1,
                next.status == force_estimate_t::STATUS_OK ? "OK" : "not OK", next.misfit);
  }
}
