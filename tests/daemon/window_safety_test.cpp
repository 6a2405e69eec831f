// Issue 10, in the window/message layer that tipforced and `tipforce invert` share
// (WindowProcessor): windows absurd for their probe are REJECTED with the reason and leave the
// stream untouched; probe names are bounded and printable; every estimate that is not OK says why.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <functional>

#include "testlib.hpp"
#include "tipforce/backend.hpp"
#include "tipforce/window_processor.hpp"

using namespace tfdtest;
using tipforce::deflection_window_t;
using tipforce::force_estimate_t;

namespace {

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

// One absurd window in a long scan: REJECTED, and the windows after it come back as they do
// without it, from the one after next on (issue 10: the next 246 came back NOT_CONVERGED).
TEST(Poisoning, OneAbsurdWindowDoesNotSpoilTheWindowsAfterIt) {
  const int n = 1024, bad = 300;
  tipforce::Config config = tipforce::parse_config(test_config(64, 0.25, 3), "test.toml");
  ScanOptions so;
  so.windows = n;
  // The scan the file-mode tests invert well (1250 samples, 25 drive periods per window): on a scan
  // whose fits are themselves unstable, any change at all would ripple on.
  std::vector<TruthRow> truth;
  const std::vector<Event> scan = make_scan(config, so, &truth);
  auto backend = tipforce::make_backend("cpu");
  auto run = [&](const std::function<void(deflection_window_t&)>& spoil) {
    tipforce::lcmio::WindowProcessor processor(config, *backend.backend);
    std::vector<force_estimate_t> out;
    for (int i = 0; i < n; ++i) {
      std::vector<std::uint8_t> bytes = scan[static_cast<std::size_t>(i)].data;
      if (i == bad && spoil) {
        auto w = decode<deflection_window_t>(scan[static_cast<std::size_t>(i)]);
        spoil(*w);
        bytes = encode(*w);
      }
      auto r = processor.process(bytes.data(), bytes.size(), 0);
      out.push_back(*r.estimate);
    }
    return out;
  };
  const auto clean = run(nullptr);
  // Beyond the next window: how many fits are NOT_CONVERGED, and how many are within 5 % (k) and
  // 0.5 nm (h) of the truth. The chain of warm starts is sensitive (the clean run itself has
  // windows that jump out of contact, and what follows them differs with any change upstream),
  // so the spoiled run is held to the clean run's quality, not to its exact numbers.
  auto quality = [&](const std::vector<force_estimate_t>& est, int& not_converged, int& accurate) {
    not_converged = accurate = 0;
    for (int i = bad + 2; i < n; ++i) {
      const auto& e = est[static_cast<std::size_t>(i)];
      if (e.status == force_estimate_t::STATUS_NOT_CONVERGED) ++not_converged;
      double k = 0, h = 0;
      for (std::size_t j = 0; j < e.param_names.size(); ++j) {
        if (e.param_names[j] == "k_n_per_m") k = e.params[j];
        if (e.param_names[j] == "h_m") h = e.params[j];
      }
      const auto& t = truth[static_cast<std::size_t>(i)].values;
      if (std::abs(k / t.at("k_n_per_m") - 1) < 0.05 && std::abs(h - t.at("h_m")) < 0.5e-9) ++accurate;
    }
  };
  int clean_nc = 0, clean_acc = 0;
  quality(clean, clean_nc, clean_acc);
  for (const auto& [what, spoil] :
       std::vector<std::pair<std::string, std::function<void(deflection_window_t&)>>>{
           {"drive_amplitude_m = 1e30", [](deflection_window_t& w) { w.drive_amplitude_m = 1e30; }},
           {"drive_frequency_hz = 1e12", [](deflection_window_t& w) { w.drive_frequency_hz = 1e12; }}}) {
    const auto spoiled = run(spoil);
    EXPECT_EQ(spoiled[bad].status, force_estimate_t::STATUS_REJECTED) << what;
    int differing = 0, status_changed = 0, beyond = 0, outside_2sigma = 0, first_differing = -1;
    double worst_rel = 0;
    for (int i = 0; i < n; ++i) {
      if (i == bad) continue;
      const auto& a = clean[static_cast<std::size_t>(i)];
      const auto& b = spoiled[static_cast<std::size_t>(i)];
      if (i < bad) {
        EXPECT_EQ(a.params, b.params) << "seq " << i << " before the absurd window";
        continue;
      }
      double rel = 0;
      bool within = a.params.size() == b.params.size();
      for (std::size_t k = 0; within && k < a.params.size(); ++k) {
        const double d = std::abs(a.params[k] - b.params[k]);
        rel = std::max(rel, d / std::max(std::abs(a.params[k]), 1e-30));
        if (!(d <= 2 * std::max(a.param_sigma[k], b.param_sigma[k]))) within = false;
      }
      if (rel > 0) ++differing;
      if (i <= bad + 1) continue;
      if (first_differing < 0 && !within) first_differing = i;
      ++beyond;
      if (a.status != b.status) ++status_changed;
      if (!within) ++outside_2sigma;
      worst_rel = std::max(worst_rel, rel);
      if (std::getenv("POISON_DEBUG") && (a.status != b.status || !within))
        std::printf("seq %d: clean %d [%g %g] | spoiled %d [%g %g] %s\n", i, a.status, a.params[0], a.params[1],
                    b.status, b.params[0], b.params[1], b.message.c_str());
    }
    int nc = 0, acc = 0;
    quality(spoiled, nc, acc);
    // The finding: 246 (or 108) NOT_CONVERGED windows after one absurd window.
    EXPECT_LE(nc, clean_nc + 3) << what;
    EXPECT_GE(acc, clean_acc - beyond / 100) << what;
    EXPECT_EQ(spoiled[bad + 1].status, force_estimate_t::STATUS_OK) << what << ": " << spoiled[bad + 1].message;
    std::printf("%s at seq %d of %d: REJECTED (%s). Next window: status %d. Beyond it (%d windows): NOT_CONVERGED %d "
                "(clean run %d), accurate %d (clean run %d); status changed %d, outside 2 sigma of the clean run %d, "
                "first differing seq %d\n",
                what.c_str(), bad, n, spoiled[bad].message.c_str(), spoiled[bad + 1].status, beyond, nc, clean_nc,
                acc, clean_acc, status_changed, outside_2sigma, first_differing);
  }
}
