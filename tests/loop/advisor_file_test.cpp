// The setpoint advisor in tipforced and `tipforce invert` on log files (issue 13; no network):
// one setpoint_command_t per estimate of a probe with an advisor table, none for other probes,
// NO_ADVICE (with the reason) for a window that was REJECTED, and the same commands from both
// programs, since both answer windows through WindowProcessor.
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <map>

#include "testlib.hpp"
#include "tipforce/setpoint_command_t.hpp"

namespace {

using namespace tfdtest;
using tipforce::force_estimate_t;
using tipforce::setpoint_command_t;

std::string file_url(const fs::path& p, const std::string& query) { return "file://" + p.string() + query; }

struct Logged {
  std::vector<force_estimate_t> estimates;
  std::vector<setpoint_command_t> commands;
};
Logged read_outputs(const fs::path& log) {
  Logged o;
  for (const Event& e : read_log(log)) {
    if (e.channel == "TIPFORCE_ESTIMATE") {
      if (auto m = decode<force_estimate_t>(e)) o.estimates.push_back(*m);
    } else if (e.channel == "TIPFORCE_SETPOINT") {
      if (auto m = decode<setpoint_command_t>(e)) o.commands.push_back(*m);
    }
  }
  return o;
}

TEST(AdvisorFileMode, OneCommandPerEstimateOfTheAdvisedProbeAndTheSameFromTipforceInvert) {
  const char* tipforced = std::getenv("TIPFORCED");
  const char* cli = std::getenv("TIPFORCE_CLI");
  if (!tipforced || !cli) GTEST_SKIP() << "TIPFORCED or TIPFORCE_CLI not set";
  const fs::path dir = fs::path(std::getenv("LOOP_TMP") ? std::getenv("LOOP_TMP") : "/tmp") / "advisor-file-mode";
  fs::remove_all(dir);
  fs::create_directories(dir);
  // test_config's probe "tip" (three modes, k and h unknown) with an advisor whose limit its
  // pixels (1-2 nN) exceed, the free amplitude (15.6 nm) allowed down to 12 nm; and a probe
  // without one. The scan taps hard (h about half the free amplitude), where retracting hardly
  // lowers the peak force of the next window: the advisor lowers the amplitude there.
  const std::string config_text = test_config() +
                                  "[probe.tip.advisor]\nmax_peak_force_n = 1.5e-9\nmax_z_step_m = 1e-9\n"
                                  "min_free_amplitude_m = 12e-9\n"
                                  "[probe.other]\nf1_hz = 25000\nk_c_n_per_m = 1.3\nmodes = 3\nmodel = \"spring\"\n"
                                  "unknowns = { k_n_per_m = [0.1, 20.0], h_m = [0.0, 60e-9] }\n";
  write_text(dir / "c.toml", config_text);
  const tipforce::Config config = tipforce::load_config(dir / "c.toml");
  ScanOptions so;
  so.windows = 24;
  std::vector<Event> events = make_scan(config, so);
  // A window of the advised probe that is REJECTED (sample period < 0), and one of the other probe.
  tipforce::deflection_window_t bad = small_window("tip", 24);
  bad.sample_period_s = -1;
  events.push_back(Event{"TIPFORCE_WINDOW", events.back().timestamp + 1000, encode(bad)});
  events.push_back(Event{"TIPFORCE_WINDOW", events.back().timestamp + 1000, encode(small_window("other", 0))});
  write_log(dir / "scan.lcmlog", events);

  Child d = spawn({tipforced, "--config", (dir / "c.toml").string(), "--input-url",
                   file_url(dir / "scan.lcmlog", "?speed=0"), "--output-url", file_url(dir / "daemon.lcmlog", "?mode=w")},
                  dir / "daemon.txt");
  ASSERT_EQ(d.wait(std::chrono::seconds(120)), 0) << read_text(dir / "daemon.txt");
  Child c = spawn({cli, "invert", "--config", (dir / "c.toml").string(), "--in", (dir / "scan.lcmlog").string(), "--out",
                   (dir / "cli.lcmlog").string()},
                  dir / "cli.txt");
  ASSERT_EQ(c.wait(std::chrono::seconds(120)), 0) << read_text(dir / "cli.txt");

  const Logged daemon = read_outputs(dir / "daemon.lcmlog"), invert = read_outputs(dir / "cli.lcmlog");
  ASSERT_EQ(daemon.estimates.size(), 26u);
  ASSERT_EQ(daemon.commands.size(), 25u) << "one per estimate of probe tip, none for probe other";
  std::map<int, int> statuses;
  for (std::size_t i = 0; i < daemon.commands.size(); ++i) {
    const setpoint_command_t& cmd = daemon.commands[i];
    EXPECT_EQ(cmd.probe, "tip");
    EXPECT_EQ(cmd.seq, static_cast<std::int64_t>(i));
    EXPECT_FALSE(cmd.reason.empty());
    EXPECT_DOUBLE_EQ(cmd.max_peak_force_n, 1.5e-9);
    ++statuses[cmd.status];
    if (cmd.status == setpoint_command_t::STATUS_CORRECTION || cmd.status == setpoint_command_t::STATUS_OUT_OF_RANGE) {
      EXPECT_GE(cmd.z_offset_m, 0);
      EXPECT_LE(cmd.z_offset_m, 1e-9);
      EXPECT_LE(cmd.free_amplitude_m, cmd.current_free_amplitude_m);
      EXPECT_GE(cmd.free_amplitude_m, 12e-9 * (1 - 1e-12));
      EXPECT_LT(cmd.predicted_peak_force_n, cmd.hold_peak_force_n);
    }
    if (cmd.status == setpoint_command_t::STATUS_CORRECTION) {
      EXPECT_LE(cmd.predicted_peak_force_n + cmd.predicted_peak_force_sigma_n, cmd.target_peak_force_n * (1 + 1e-9));
    }
    if (cmd.status == setpoint_command_t::STATUS_UNDER_LIMIT) {
      EXPECT_LE(cmd.hold_peak_force_n + cmd.hold_peak_force_sigma_n, cmd.target_peak_force_n * (1 + 1e-9));
      EXPECT_EQ(cmd.z_offset_m, 0);
      EXPECT_EQ(cmd.free_amplitude_m, cmd.current_free_amplitude_m);
    }
  }
  const setpoint_command_t& rejected = daemon.commands.back();
  EXPECT_EQ(rejected.seq, 24);
  EXPECT_EQ(rejected.status, setpoint_command_t::STATUS_NO_ADVICE);
  EXPECT_NE(rejected.reason.find("REJECTED"), std::string::npos) << rejected.reason;
  EXPECT_TRUE(std::isnan(rejected.predicted_peak_force_n));
  EXPECT_EQ(rejected.z_offset_m, 0);
  std::printf("commands: %d under the limit, %d corrections, %d out of range, %d no advice\n",
              statuses[setpoint_command_t::STATUS_UNDER_LIMIT], statuses[setpoint_command_t::STATUS_CORRECTION],
              statuses[setpoint_command_t::STATUS_OUT_OF_RANGE], statuses[setpoint_command_t::STATUS_NO_ADVICE]);
  EXPECT_GT(statuses[setpoint_command_t::STATUS_CORRECTION] + statuses[setpoint_command_t::STATUS_OUT_OF_RANGE], 0)
      << "the limit was meant to be exceeded";
  EXPECT_LE(statuses[setpoint_command_t::STATUS_NO_ADVICE], 3) << "the rejected window and at most a couple of fits";
  EXPECT_NE(read_text(dir / "daemon.txt").find("25 setpoint commands"), std::string::npos) << read_text(dir / "daemon.txt");
  EXPECT_NE(read_text(dir / "cli.txt").find("setpoint commands 25"), std::string::npos) << read_text(dir / "cli.txt");

  ASSERT_EQ(invert.commands.size(), daemon.commands.size());
  for (std::size_t i = 0; i < daemon.commands.size(); ++i) {
    const setpoint_command_t &a = daemon.commands[i], &b = invert.commands[i];
    EXPECT_EQ(a.seq, b.seq);
    EXPECT_EQ(a.status, b.status);
    EXPECT_EQ(a.reason, b.reason);
    const auto same = [](double x, double y) { return x == y || (std::isnan(x) && std::isnan(y)); };
    EXPECT_TRUE(same(a.predicted_peak_force_n, b.predicted_peak_force_n)) << "seq " << a.seq;
    EXPECT_TRUE(same(a.z_offset_m, b.z_offset_m)) << "seq " << a.seq;
    EXPECT_TRUE(same(a.free_amplitude_m, b.free_amplitude_m)) << "seq " << a.seq;
    EXPECT_EQ(a.forward_solves, b.forward_solves);
  }
}

}  // namespace

namespace {

// The simulated microscope's own errors: options that only --live takes, and an answer that never
// comes (memq://, nothing listening).
TEST(SimulateLive, RefusesLiveOptionsWithoutLiveAndFailsWhenNoAnswerComes) {
  const char* cli = std::getenv("TIPFORCE_CLI");
  if (!cli) GTEST_SKIP() << "TIPFORCE_CLI not set";
  const fs::path dir = fs::path(std::getenv("LOOP_TMP") ? std::getenv("LOOP_TMP") : "/tmp") / "simulate-live";
  fs::remove_all(dir);
  fs::create_directories(dir);
  write_text(dir / "c.toml", test_config());
  write_text(dir / "s.toml", "sample_period_s = 2e-7\nsamples_per_window = 400\npixels_x = 2\nstart = \"rest\"\n"
                             "[drive]\nkind = \"sine\"\namplitude_m = 0.1e-9\nfrequency_hz = 25468.9\n"
                             "[truth]\nk_n_per_m = 2.0\nh_m = 10e-9\n");
  const std::vector<std::string> base{cli, "simulate", "--config", (dir / "c.toml").string(), "--probe", "tip",
                                      "--scan", (dir / "s.toml").string(), "--out", (dir / "truth.csv").string()};
  auto run = [&](std::vector<std::string> extra, const std::string& log) {
    std::vector<std::string> argv = base;
    argv.insert(argv.end(), extra.begin(), extra.end());
    Child c = spawn(argv, dir / log);
    return c.wait(std::chrono::seconds(60));
  };
  auto code = run({"--lockstep", "estimate"}, "no_live.txt");
  EXPECT_TRUE(code && *code != 0);
  EXPECT_NE(read_text(dir / "no_live.txt").find("--live"), std::string::npos) << read_text(dir / "no_live.txt");
  code = run({"--live", "--integrator", "fast"}, "fast.txt");
  EXPECT_TRUE(code && *code != 0);
  EXPECT_NE(read_text(dir / "fast.txt").find("excludes"), std::string::npos) << read_text(dir / "fast.txt");
  code = run({"--live", "--lcm-url", "memq://", "--lockstep", "estimate", "--timeout-s", "0.5"}, "timeout.txt");
  EXPECT_EQ(code, 1) << read_text(dir / "timeout.txt");
  EXPECT_NE(read_text(dir / "timeout.txt").find("no force_estimate_t on TIPFORCE_ESTIMATE for window 0 within"),
            std::string::npos)
      << read_text(dir / "timeout.txt");
}

}  // namespace
