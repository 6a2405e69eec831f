// End-to-end tests of the real tipforced binary (SPEC sections 3-5, issue 3 acceptance points).
//   ConfigError.*  point 6: a bad configuration stops tipforced before it subscribes
//   FileMode.*     point 2: offline reprocessing of a log, same estimates as WindowProcessor /
//                  `tipforce invert`, exit 0 at the end of the log, back-pressure instead of drops
//   BadInput.*     point 4: malformed input, each followed by a good window still answered well
//   Live.*         point 1: udpm, lcm-logplayer in, lcm-logger out, accuracy, stats
//   Overload.*     point 3: replay far faster than the solver, small queue
//   Shutdown.*     point 5: SIGTERM with windows queued; systemd notifications
// Live, Overload and Shutdown need udpm and run inside a private network namespace
// (netns_run.sh); they skip when TFD_IN_NETNS is not set.
#include <gtest/gtest.h>
#include <signal.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <set>

#include <lcm/lcm-cpp.hpp>

#include "tipforce/latency_stats_t.hpp"
#include "tipforce/percentile.hpp"
#include "testlib.hpp"
#include "tipforce/backend.hpp"
#include "tipforce/window_processor.hpp"

using namespace tfdtest;
using namespace std::chrono_literals;
using tipforce::deflection_window_t;
using tipforce::force_estimate_t;
using tipforce::latency_stats_t;

namespace {

const char* const kUdpmUrl = "udpm://239.255.76.67:7667?ttl=0";

std::string env_or_empty(const char* name) {
  const char* v = std::getenv(name);
  return v ? v : "";
}

struct Paths {
  std::string tipforced, tool, cli, logger, player;
  fs::path dir;
};

// The binaries and a fresh directory for one test.
Paths setup(const std::string& name) {
  Paths p;
  p.tipforced = env_or_empty("TIPFORCED");
  p.tool = env_or_empty("TFD_TOOL");
  p.cli = env_or_empty("TIPFORCE_CLI");
  p.logger = env_or_empty("LCM_LOGGER");
  p.player = env_or_empty("LCM_LOGPLAYER");
  fs::path base = env_or_empty("TFD_TMP");
  if (base.empty()) base = fs::temp_directory_path() / "tipforced-tests";
  p.dir = base / name;
  fs::remove_all(p.dir);
  fs::create_directories(p.dir);
  return p;
}

bool in_netns() { return env_or_empty("TFD_IN_NETNS") == "1"; }

struct Outputs {
  std::vector<force_estimate_t> estimates;
  std::vector<latency_stats_t> stats;
};

Outputs read_outputs(const fs::path& log) {
  Outputs o;
  for (const Event& e : read_log(log)) {
    if (e.channel == "TIPFORCE_ESTIMATE") {
      if (auto m = decode<force_estimate_t>(e)) o.estimates.push_back(*m);
    } else if (e.channel == "TIPFORCE_STATS") {
      if (auto m = decode<latency_stats_t>(e)) o.stats.push_back(*m);
    }
  }
  return o;
}

double param(const force_estimate_t& e, const std::string& name) {
  for (int i = 0; i < e.n_params; ++i)
    if (e.param_names[static_cast<std::size_t>(i)] == name) return e.params[static_cast<std::size_t>(i)];
  return std::nan("");
}

// Fraction of estimates (by seq) whose k and h are close to the truth.
struct Accuracy {
  int compared = 0, good = 0;
  double median_k_rel = 0, median_h_abs_nm = 0;
};
Accuracy accuracy(const std::vector<force_estimate_t>& estimates, const std::vector<TruthRow>& truth) {
  Accuracy a;
  std::vector<double> k_rel, h_abs;
  for (const auto& e : estimates) {
    if (e.probe != "tip" || e.seq < 0 || e.seq >= static_cast<int64_t>(truth.size())) continue;
    if (e.status == force_estimate_t::STATUS_REJECTED) continue;
    const TruthRow& t = truth[static_cast<std::size_t>(e.seq)];
    const double kr = std::abs(param(e, "k_n_per_m") / t.values.at("k_n_per_m") - 1);
    const double ha = std::abs(param(e, "h_m") - t.values.at("h_m")) * 1e9;
    ++a.compared;
    if (kr < 0.05 && ha < 0.5) ++a.good;
    k_rel.push_back(kr);
    h_abs.push_back(ha);
  }
  a.median_k_rel = tipforce::percentile(k_rel, 0.5);
  a.median_h_abs_nm = tipforce::percentile(h_abs, 0.5);
  return a;
}

std::string file_url(const fs::path& p, const std::string& query) { return "file://" + p.string() + query; }

// Runs tipforced to completion on a log file; returns the exit code.
int run_file_mode(const Paths& p, const fs::path& config, const fs::path& in, const fs::path& out,
                  const fs::path& stderr_log, std::chrono::seconds timeout = 120s) {
  Child c = spawn({p.tipforced, "--config", config.string(), "--input-url", file_url(in, "?speed=0"),
                   "--output-url", file_url(out, "?mode=w")},
                  stderr_log);
  auto code = c.wait(timeout);
  if (!code) {
    c.kill_and_reap();
    return -1;
  }
  return *code;
}

}  // namespace

// ---- point 6: configuration errors ------------------------------------------------------------

class ConfigError : public ::testing::Test {
 protected:
  // Runs tipforced on `config_text`, expects a non-zero exit before it subscribes (no start-up
  // line, no READY=1) and a message naming the file and `key`.
  void expect_refused(const std::string& config_text, const std::string& key, const std::string& name) {
    Paths p = setup("config-" + name);
    const fs::path cfg = p.dir / "bad.toml";
    write_text(cfg, config_text);
    NotifyListener notify(p.dir / "notify.sock");
    Child c = spawn({p.tipforced, "--config", cfg.string(), "--input-url", "memq://"}, p.dir / "stderr.txt",
                    {{"NOTIFY_SOCKET", notify.path().string()}});
    auto code = c.wait(30s);
    if (!code) c.kill_and_reap();
    ASSERT_TRUE(code) << "tipforced did not exit";
    EXPECT_NE(*code, 0);
    const std::string err = read_text(p.dir / "stderr.txt");
    EXPECT_NE(err.find(cfg.string()), std::string::npos) << err;
    EXPECT_NE(err.find(key), std::string::npos) << err;
    EXPECT_EQ(err.find("started"), std::string::npos) << err;
    EXPECT_EQ(notify.receive(100ms), "") << "READY sent despite the configuration error";
  }
};

TEST_F(ConfigError, WrongTypeNamesFileAndKey) {
  std::string text = test_config();
  text.replace(text.find("queue_capacity = 64"), 19, "queue_capacity = \"many\"");
  expect_refused(text, "daemon.queue_capacity", "type");
}

TEST_F(ConfigError, UnknownKeyNamesFileAndKey) {
  std::string text = test_config();
  text.insert(text.find("[probe.tip.inversion]"), "colour = \"red\"\n");
  expect_refused(text, "probe.tip.colour", "unknown-key");
}

TEST_F(ConfigError, InvertedBoundsNameFileAndKey) {
  std::string text = test_config();
  text.replace(text.find("k_n_per_m = [0.1, 20.0]"), 23, "k_n_per_m = [20.0, 0.1]");
  expect_refused(text, "k_n_per_m", "bounds");
}

TEST_F(ConfigError, MissingFileIsNamed) {
  Paths p = setup("config-missing");
  Child c = spawn({p.tipforced, "--config", (p.dir / "nope.toml").string()}, p.dir / "stderr.txt");
  auto code = c.wait(30s);
  ASSERT_TRUE(code);
  EXPECT_NE(*code, 0);
  EXPECT_NE(read_text(p.dir / "stderr.txt").find("nope.toml"), std::string::npos);
}

TEST_F(ConfigError, FileInputWithoutOutputIsRefused) {
  Paths p = setup("config-file-no-output");
  const fs::path cfg = p.dir / "c.toml";
  write_text(cfg, test_config());
  write_log(p.dir / "in.lcmlog", {Event{"TIPFORCE_WINDOW", 1, encode(small_window("tip", 0))}});
  Child c = spawn({p.tipforced, "--config", cfg.string(), "--input-url", file_url(p.dir / "in.lcmlog", "?speed=0")},
                  p.dir / "stderr.txt");
  auto code = c.wait(30s);
  ASSERT_TRUE(code);
  EXPECT_NE(*code, 0);
  EXPECT_NE(read_text(p.dir / "stderr.txt").find("daemon.output_url"), std::string::npos);
}

// ---- point 2: file mode -----------------------------------------------------------------------

TEST(FileMode, SameEstimatesAsWindowProcessorAndExitsAtEndOfLog) {
  Paths p = setup("file-mode");
  const fs::path cfg = p.dir / "c.toml", in = p.dir / "scan.lcmlog", out = p.dir / "out.lcmlog";
  write_text(cfg, test_config());
  const tipforce::Config config = tipforce::load_config(cfg);
  ScanOptions so;
  so.windows = 30;
  std::vector<TruthRow> truth;
  write_log(in, make_scan(config, so, &truth));

  const auto t0 = std::chrono::steady_clock::now();
  ASSERT_EQ(run_file_mode(p, cfg, in, out, p.dir / "stderr.txt"), 0) << read_text(p.dir / "stderr.txt");
  const double took = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  Outputs o = read_outputs(out);
  ASSERT_EQ(o.estimates.size(), 30u);
  ASSERT_FALSE(o.stats.empty());
  const latency_stats_t& last = o.stats.back();
  EXPECT_EQ(last.windows_received, 30);
  EXPECT_EQ(last.windows_done, 30);
  EXPECT_EQ(last.windows_dropped, 0);
  EXPECT_EQ(last.queue_depth, 0);

  // The same windows through WindowProcessor in this process: what `tipforce invert` does.
  auto backend = tipforce::make_backend("cpu");
  tipforce::lcmio::WindowProcessor processor(config, *backend.backend);
  int i = 0;
  for (const Event& e : read_log(in)) {
    auto r = processor.process(e.data.data(), e.data.size(), 0);
    ASSERT_TRUE(r.estimate);
    const force_estimate_t& a = o.estimates[static_cast<std::size_t>(i++)];
    const force_estimate_t& b = *r.estimate;
    EXPECT_EQ(a.seq, b.seq);
    EXPECT_EQ(a.status, b.status);
    EXPECT_EQ(a.param_names, b.param_names);
    EXPECT_EQ(a.params, b.params) << "seq " << a.seq;
    EXPECT_EQ(a.param_sigma, b.param_sigma);
    EXPECT_EQ(a.iterations, b.iterations);
    EXPECT_EQ(a.forward_solves, b.forward_solves);
    EXPECT_TRUE(a.misfit == b.misfit || (std::isnan(a.misfit) && std::isnan(b.misfit)));
  }
  const Accuracy acc = accuracy(o.estimates, truth);
  EXPECT_GE(acc.good, acc.compared * 9 / 10) << "median |dk/k| " << acc.median_k_rel << ", median |dh| "
                                              << acc.median_h_abs_nm << " nm";
  std::printf("file mode: 30 windows in %.2f s; %d/%d within 5%% (k) and 0.5 nm (h); median |dk/k| %.2g, |dh| %.2g nm\n",
              took, acc.good, acc.compared, acc.median_k_rel, acc.median_h_abs_nm);

  // And through the real `tipforce invert`, where the lead's command is built.
  if (!p.cli.empty()) {
    const fs::path cli_out = p.dir / "cli.lcmlog";
    Child c = spawn({p.cli, "invert", "--config", cfg.string(), "--in", in.string(), "--out", cli_out.string()},
                    p.dir / "cli.txt");
    auto code = c.wait(120s);
    ASSERT_TRUE(code);
    ASSERT_EQ(*code, 0) << read_text(p.dir / "cli.txt");
    Outputs cli = read_outputs(cli_out);
    ASSERT_EQ(cli.estimates.size(), o.estimates.size());
    for (std::size_t k = 0; k < cli.estimates.size(); ++k) {
      EXPECT_EQ(cli.estimates[k].seq, o.estimates[k].seq);
      EXPECT_EQ(cli.estimates[k].status, o.estimates[k].status);
      EXPECT_EQ(cli.estimates[k].params, o.estimates[k].params);
      EXPECT_EQ(cli.estimates[k].param_sigma, o.estimates[k].param_sigma);
    }
  } else {
    std::printf("note: the tipforce command is not built here; compared with WindowProcessor only\n");
  }
}

TEST(FileMode, SmallQueueAppliesBackPressureInsteadOfDropping) {
  Paths p = setup("file-backpressure");
  const fs::path cfg = p.dir / "c.toml", in = p.dir / "scan.lcmlog", out = p.dir / "out.lcmlog";
  write_text(cfg, test_config(/*queue_capacity=*/1));
  ScanOptions so;
  so.windows = 25;
  so.samples = 600;
  write_log(in, make_scan(tipforce::load_config(cfg), so));
  ASSERT_EQ(run_file_mode(p, cfg, in, out, p.dir / "stderr.txt"), 0) << read_text(p.dir / "stderr.txt");
  Outputs o = read_outputs(out);
  EXPECT_EQ(o.estimates.size(), 25u);
  ASSERT_FALSE(o.stats.empty());
  EXPECT_EQ(o.stats.back().windows_dropped, 0);
  EXPECT_EQ(o.stats.back().windows_done, 25);
  std::set<int64_t> seqs;
  for (const auto& e : o.estimates) seqs.insert(e.seq);
  EXPECT_EQ(seqs.size(), 25u);
}

// ---- point 4: bad input -----------------------------------------------------------------------

namespace {

struct BadCase {
  std::string name;
  std::vector<std::uint8_t> bytes;
  bool attributable;
  std::string expect_in_message;  // for attributable ones
};

// Overwrites n_samples in an encoded window (big-endian int32 after the drive fields).
void patch_n_samples(std::vector<std::uint8_t>& bytes, const std::string& probe, int32_t n) {
  const std::size_t off = 8 + 8 + (4 + probe.size() + 1) + 8 + 4 + 4 + 1 + 8 + 8 + 1 + 4 * 8;
  const auto u = static_cast<std::uint32_t>(n);
  for (int k = 0; k < 4; ++k) bytes[off + static_cast<std::size_t>(k)] = static_cast<std::uint8_t>(u >> (24 - 8 * k));
}

std::vector<BadCase> bad_cases() {
  std::vector<BadCase> cases;
  std::mt19937 rng(3);
  std::vector<std::uint8_t> random(333);
  for (auto& b : random) b = static_cast<std::uint8_t>(rng());
  cases.push_back({"random bytes", random, false, ""});
  latency_stats_t other{};
  other.backend = "not a window";
  cases.push_back({"another LCM type", encode(other), false, ""});
  {
    auto bytes = encode(small_window("tip", 1001));
    patch_n_samples(bytes, "tip", 5000);
    cases.push_back({"n_samples disagreeing with the array", bytes, true, "disagrees"});
  }
  {
    auto w = small_window("tip", 1002);
    w.deflection_m[17] = std::nanf("");
    cases.push_back({"NaN sample", encode(w), true, "not finite"});
  }
  {
    auto w = small_window("tip", 1003);
    w.sample_period_s = 0;
    cases.push_back({"sample period 0", encode(w), true, "sample_period"});
  }
  {
    auto w = small_window("tip", 1004);
    w.sample_period_s = -1e-6;
    cases.push_back({"negative sample period", encode(w), true, "sample_period"});
  }
  cases.push_back({"unknown probe", encode(small_window("no_such_probe", 1005)), true, "unknown probe"});
  cases.push_back({"2,000,000 samples", encode(small_window("tip", 1006, 2'000'000)), true, "limit"});
  {
    auto w = small_window("tip", 1007, 0);
    cases.push_back({"no samples", encode(w), true, "positive"});
  }
  return cases;
}

// The bad cases interleaved with a good scan: good 0, bad 0, good 1, bad 1, ..., good N.
std::vector<Event> interleave(const std::vector<BadCase>& cases, const std::vector<Event>& scan) {
  std::vector<Event> events;
  for (std::size_t i = 0; i < scan.size(); ++i) {
    events.push_back(scan[i]);
    if (i < cases.size()) events.push_back(Event{"TIPFORCE_WINDOW", scan[i].timestamp + 1, cases[i].bytes});
  }
  return events;
}

void check_bad_input_outputs(const Outputs& o, const std::vector<BadCase>& cases, const std::vector<TruthRow>& truth,
                             std::size_t n_good, const std::string& log_text) {
  std::size_t attributable = 0;
  for (const auto& c : cases) attributable += c.attributable ? 1 : 0;
  EXPECT_EQ(o.estimates.size(), n_good + attributable);
  // Each attributable bad window: STATUS_REJECTED with the reason.
  for (const auto& c : cases) {
    if (!c.attributable) continue;
    bool found = false;
    for (const auto& e : o.estimates) {
      if (e.status == force_estimate_t::STATUS_REJECTED && e.message.find(c.expect_in_message) != std::string::npos &&
          e.seq >= 1000) {
        found = true;
        EXPECT_EQ(e.n_params, 0);
      }
    }
    EXPECT_TRUE(found) << c.name << ": no STATUS_REJECTED estimate mentioning '" << c.expect_in_message << "'";
  }
  // Each good window: answered, and well.
  std::vector<force_estimate_t> good;
  for (const auto& e : o.estimates)
    if (e.seq < 1000 && e.probe == "tip") good.push_back(e);
  ASSERT_EQ(good.size(), n_good);
  for (const auto& e : good) EXPECT_NE(e.status, force_estimate_t::STATUS_REJECTED) << e.message;
  const Accuracy acc = accuracy(good, truth);
  EXPECT_GE(acc.good, acc.compared - 1) << "median |dk/k| " << acc.median_k_rel;
  // Counted in the stats, logged.
  ASSERT_FALSE(o.stats.empty());
  const auto& last = o.stats.back();
  EXPECT_EQ(last.windows_received, static_cast<int64_t>(n_good + cases.size()));
  EXPECT_EQ(last.windows_rejected, static_cast<int64_t>(cases.size()));
  EXPECT_EQ(last.windows_done, static_cast<int64_t>(n_good + attributable));
  EXPECT_EQ(last.windows_dropped, 0);
  std::size_t warnings = 0;
  for (std::size_t pos = 0; (pos = log_text.find("[warning]", pos)) != std::string::npos; ++pos) ++warnings;
  EXPECT_EQ(warnings, cases.size()) << log_text;
  EXPECT_NE(log_text.find("not a tipforce.deflection_window_t"), std::string::npos);
  EXPECT_NE(log_text.find("rejected window probe 'no_such_probe'"), std::string::npos);
}

}  // namespace

TEST(BadInput, EachKindIsRejectedAndTheNextGoodWindowStillAnswered) {
  Paths p = setup("bad-input");
  const fs::path cfg = p.dir / "c.toml", in = p.dir / "in.lcmlog", out = p.dir / "out.lcmlog";
  write_text(cfg, test_config());
  const auto cases = bad_cases();
  ScanOptions so;
  so.windows = static_cast<int>(cases.size()) + 1;
  std::vector<TruthRow> truth;
  auto scan = make_scan(tipforce::load_config(cfg), so, &truth);
  write_log(in, interleave(cases, scan));
  ASSERT_EQ(run_file_mode(p, cfg, in, out, p.dir / "stderr.txt"), 0) << read_text(p.dir / "stderr.txt");
  check_bad_input_outputs(read_outputs(out), cases, truth, scan.size(), read_text(p.dir / "stderr.txt"));
}

// ---- udpm tests (inside a network namespace) ----------------------------------------------------

namespace {

// tipforced on udpm (testlib's LiveProcess), started the way these tests start it.
struct LiveDaemon : LiveProcess {
  bool start(const Paths& p, const fs::path& cfg, const std::string& output_url,
             const std::map<std::string, std::string>& extra_env = {}, const std::string& input_url = kUdpmUrl) {
    return LiveProcess::start(p.tipforced, p.dir, cfg, input_url, output_url, extra_env);
  }
};

int count_estimates(const fs::path& log) {
  int n = 0;
  for (const Event& e : read_log(log)) n += e.channel == "TIPFORCE_ESTIMATE";
  return n;
}

}  // namespace

TEST(Live, ScanReplayedWithLcmLogplayerRecordedWithLcmLogger) {
  if (!in_netns()) GTEST_SKIP() << "needs a network namespace (run through netns_run.sh)";
  Paths p = setup("live");
  if (p.logger.empty() || p.player.empty()) GTEST_SKIP() << "lcm-logger / lcm-logplayer not found";
  const fs::path cfg = p.dir / "c.toml", in = p.dir / "scan.lcmlog", rec = p.dir / "recorded.lcmlog";
  write_text(cfg, test_config(64, 0.25));
  ScanOptions so;
  so.windows = 60;
  so.spacing_s = 0.01;  // 100 windows/s
  std::vector<TruthRow> truth;
  write_log(in, make_scan(tipforce::load_config(cfg), so, &truth));
  write_truth_csv(p.dir / "scan.truth.csv", truth);

  Child logger = spawn({p.logger, "-f", std::string("--lcm-url=") + kUdpmUrl, "--channel=TIPFORCE_(ESTIMATE|STATS)", rec.string()},
                       p.dir / "logger.txt");
  LiveDaemon d;
  ASSERT_TRUE(d.start(p, cfg, "")) << read_text(p.dir / "stderr.txt");
  std::this_thread::sleep_for(300ms);  // lcm-logger subscribed
  ASSERT_FALSE(logger.wait(0ms)) << "lcm-logger exited: " << read_text(p.dir / "logger.txt");
  Child player = spawn({p.player, std::string("--lcm-url=") + kUdpmUrl, in.string()}, p.dir / "player.txt");
  auto player_code = player.wait(60s);
  ASSERT_TRUE(player_code);
  EXPECT_EQ(*player_code, 0);
  EXPECT_TRUE(wait_until([&] { return count_estimates(rec) >= 60; }, 60s)) << count_estimates(rec);
  std::this_thread::sleep_for(400ms);  // one more stats period
  auto [code, took] = d.stop();
  ASSERT_TRUE(code);
  EXPECT_EQ(*code, 0);
  EXPECT_LT(took, 2.0);
  std::this_thread::sleep_for(300ms);  // final stats recorded
  logger.signal(SIGINT);
  ASSERT_TRUE(logger.wait(10s));

  Outputs o = read_outputs(rec);
  ASSERT_EQ(o.estimates.size(), 60u);
  std::set<int64_t> seqs;
  for (const auto& e : o.estimates) {
    seqs.insert(e.seq);
    EXPECT_NE(e.status, force_estimate_t::STATUS_REJECTED) << "seq " << e.seq << ": " << e.message;
    EXPECT_GE(e.publish_utime, e.receive_utime);
  }
  EXPECT_EQ(seqs.size(), 60u);
  const Accuracy acc = accuracy(o.estimates, truth);
  // A few pixels of the synthetic scan are not identifiable (the library says so with
  // STATUS_NOT_CONVERGED); the daemon's part is to give exactly what WindowProcessor gives.
  EXPECT_GE(acc.good, 48) << "median |dk/k| " << acc.median_k_rel << " |dh| " << acc.median_h_abs_nm;
  EXPECT_LT(acc.median_k_rel, 0.02);
  EXPECT_LT(acc.median_h_abs_nm, 0.2);
  {
    std::vector<force_estimate_t> sorted = o.estimates;
    std::sort(sorted.begin(), sorted.end(), [](const auto& a, const auto& b) { return a.seq < b.seq; });
    const tipforce::Config config = tipforce::load_config(cfg);
    auto backend = tipforce::make_backend("cpu");
    tipforce::lcmio::WindowProcessor processor(config, *backend.backend);
    std::size_t i = 0;
    for (const Event& e : read_log(in)) {
      auto r = processor.process(e.data.data(), e.data.size(), 0);
      ASSERT_TRUE(r.estimate);
      EXPECT_EQ(sorted[i].params, r.estimate->params) << "seq " << sorted[i].seq;
      EXPECT_EQ(sorted[i].status, r.estimate->status) << "seq " << sorted[i].seq;
      ++i;
    }
  }
  ASSERT_GE(o.stats.size(), 2u);
  const auto& last = o.stats.back();
  EXPECT_EQ(last.windows_received, 60);
  EXPECT_EQ(last.windows_done, 60);
  EXPECT_EQ(last.windows_dropped, 0);
  EXPECT_EQ(last.windows_rejected, 0);
  EXPECT_EQ(last.queue_depth, 0);
  // Its own estimates come back to it on udpm; none of them is taken for another publisher's.
  EXPECT_EQ(last.foreign_estimates, 0);
  EXPECT_EQ(last.backend.rfind("cpu", 0), 0u) << last.backend;
  // Counters never go down; windows_done agrees with what was recorded.
  for (std::size_t i = 1; i < o.stats.size(); ++i) {
    EXPECT_GE(o.stats[i].windows_received, o.stats[i - 1].windows_received);
    EXPECT_GE(o.stats[i].windows_done, o.stats[i - 1].windows_done);
  }
  std::vector<double> lat;
  for (const auto& e : o.estimates) lat.push_back(static_cast<double>(e.publish_utime - e.receive_utime));
  std::printf("live: 60 windows at 100/s; %d/%d accurate; latency p50 %.0f us p99 %.0f us; %zu stats messages\n",
              acc.good, acc.compared, tipforce::percentile(lat, 0.5), tipforce::percentile(lat, 0.99),
              o.stats.size());
}

TEST(Live, BadInputOverUdpm) {
  if (!in_netns()) GTEST_SKIP() << "needs a network namespace (run through netns_run.sh)";
  Paths p = setup("live-bad");
  const fs::path cfg = p.dir / "c.toml", out = p.dir / "out.lcmlog";
  write_text(cfg, test_config(64, 0.25));
  auto cases = bad_cases();
  // 8 MB in one UDP message would need a large socket buffer; the file-mode test covers it.
  cases.erase(std::remove_if(cases.begin(), cases.end(), [](const BadCase& c) { return c.name == "2,000,000 samples"; }),
              cases.end());
  ScanOptions so;
  so.windows = static_cast<int>(cases.size()) + 1;
  std::vector<TruthRow> truth;
  auto events = interleave(cases, make_scan(tipforce::load_config(cfg), so, &truth));
  LiveDaemon d;
  ASSERT_TRUE(d.start(p, cfg, file_url(out, "?mode=w"))) << read_text(p.dir / "stderr.txt");
  lcm::LCM lcm(kUdpmUrl);
  ASSERT_TRUE(lcm.good());
  for (const Event& e : events) {
    lcm.publish(e.channel, e.data.data(), static_cast<unsigned>(e.data.size()));
    std::this_thread::sleep_for(20ms);
  }
  std::this_thread::sleep_for(1s);
  auto [code, took] = d.stop();
  ASSERT_TRUE(code);
  EXPECT_EQ(*code, 0);
  check_bad_input_outputs(read_outputs(out), cases, truth, static_cast<std::size_t>(so.windows),
                          read_text(p.dir / "stderr.txt"));
}

// ---- point 3: overload ------------------------------------------------------------------------

// Issue 9: a per-probe latency budget, counted from receipt. With deadline_ms far below any fit,
// every window is answered NOT_CONVERGED with a message that says the deadline stopped it, and
// published within the budget plus a small margin: the batch in flight when the deadline passed
// (this probe's largest, a swarm generation of 24 sets of 1250 samples and 3 modes, takes well
// under a millisecond), the final solve, and the IO thread's turn on a loaded 2-core machine.
// Half a millisecond: since 2026-12-02 a tracked window of this probe can finish within 3 ms.
// The stream's sample period is prepared, as the README tells a user with a budget to do: without
// it the first window builds the step tables (README, prepare_sample_periods_s), and on a loaded
// machine (a fresh clone's test run) that window came out 16.5 ms after receipt.
TEST(Live, TinyDeadlineAnswersEveryWindowNotConvergedWithinTheBudget) {
  if (!in_netns()) GTEST_SKIP() << "needs a network namespace (run through netns_run.sh)";
  Paths p = setup("live-deadline");
  const fs::path cfg = p.dir / "c.toml", out = p.dir / "out.lcmlog";
  const double budget_ms = 0.5, margin_ms = 15;
  ScanOptions so;
  so.windows = 30;
  write_text(cfg, test_config(64, 0.25));
  const double f1 = tipforce::load_config(cfg).probe_model(so.probe).modal.modes()[0].frequency_hz;
  // make_scan's sample period (testlib.cpp), to the last bit.
  char prepare[80];
  std::snprintf(prepare, sizeof prepare, "prepare_sample_periods_s = [%.17g]\n", 1.0 / (f1 * so.samples_per_period));
  write_text(cfg, test_config(64, 0.25) + "deadline_ms = 0.5\n" + prepare);
  const std::vector<Event> scan = make_scan(tipforce::load_config(cfg), so);
  LiveDaemon d;
  ASSERT_TRUE(d.start(p, cfg, file_url(out, "?mode=w"))) << read_text(p.dir / "stderr.txt");
  lcm::LCM lcm(kUdpmUrl);
  ASSERT_TRUE(lcm.good());
  for (const Event& e : scan) {
    lcm.publish(e.channel, e.data.data(), static_cast<unsigned>(e.data.size()));
    std::this_thread::sleep_for(40ms);  // slower than the budget: no window waits for another
  }
  std::this_thread::sleep_for(500ms);
  auto [code, took] = d.stop();
  ASSERT_TRUE(code);
  EXPECT_EQ(*code, 0);
  const Outputs o = read_outputs(out);
  ASSERT_EQ(o.estimates.size(), scan.size());
  double worst_ms = 0;
  for (const force_estimate_t& e : o.estimates) {
    EXPECT_EQ(e.status, force_estimate_t::STATUS_NOT_CONVERGED) << "seq " << e.seq << ": " << e.message;
    EXPECT_EQ(e.message.rfind("deadline of 0.5 ms (deadline_ms) from receipt", 0), 0u) << "seq " << e.seq << ": " << e.message;
    const double latency_ms = 1e-3 * static_cast<double>(e.publish_utime - e.receive_utime);
    EXPECT_LE(latency_ms, budget_ms + margin_ms) << "seq " << e.seq << ": " << e.message;
    worst_ms = std::max(worst_ms, latency_ms);
    if (std::getenv("TIPFORCE_TEST_VERBOSE"))
      std::printf("seq %ld: %.2f ms: %s\n", static_cast<long>(e.seq), latency_ms, e.message.c_str());
  }
  std::printf("deadline 0.5 ms: %zu estimates, all NOT_CONVERGED, receive->publish at most %.2f ms\n", o.estimates.size(),
              worst_ms);
}

TEST(Overload, TenTimesRealTimeWithASmallQueue) {
  if (!in_netns()) GTEST_SKIP() << "needs a network namespace (run through netns_run.sh)";
  Paths p = setup("overload");
  if (p.player.empty()) GTEST_SKIP() << "lcm-logplayer not found";
  const int capacity = 4, n = 300;
  const fs::path cfg = p.dir / "c.toml", in = p.dir / "scan.lcmlog", out = p.dir / "out.lcmlog";
  write_text(cfg, test_config(capacity, 0.25));
  ScanOptions so;
  so.windows = n;
  so.spacing_s = 0.002;  // 500 windows/s as recorded: already above what 2 cores solve
  write_log(in, make_scan(tipforce::load_config(cfg), so));
  LiveDaemon d;
  // A 4 MB socket buffer (LCM's recv_buf_size; the kernel caps it at net.core.rmem_max) so that a
  // loaded machine does not lose datagrams before tipforced sees them.
  ASSERT_TRUE(d.start(p, cfg, file_url(out, "?mode=w"), {}, std::string(kUdpmUrl) + "&recv_buf_size=4194304"))
      << read_text(p.dir / "stderr.txt");
  // Replayed at 10x: 5000 windows/s.
  Child player = spawn({p.player, "--speed=10", std::string("--lcm-url=") + kUdpmUrl, in.string()}, p.dir / "player.txt");
  auto pc = player.wait(60s);
  ASSERT_TRUE(pc);
  std::this_thread::sleep_for(1500ms);  // the queue drains
  auto [code, took] = d.stop();
  ASSERT_TRUE(code);
  EXPECT_EQ(*code, 0);
  EXPECT_LT(took, 2.0);
  Outputs o = read_outputs(out);
  ASSERT_FALSE(o.stats.empty());
  const auto& last = o.stats.back();
  EXPECT_EQ(last.windows_received, n) << "windows lost before tipforced's queue";
  EXPECT_GT(last.windows_dropped, 0);
  EXPECT_EQ(static_cast<int64_t>(o.estimates.size()), last.windows_done);
  EXPECT_EQ(last.windows_done + last.windows_dropped, last.windows_received);
  std::vector<double> lat, solve_p99;
  for (const auto& e : o.estimates) lat.push_back(static_cast<double>(e.publish_utime - e.receive_utime));
  double max_solve_p99 = 0, max_lat_p99 = 0;
  for (const auto& s : o.stats) {
    max_solve_p99 = std::max(max_solve_p99, s.solve_p99_us);
    max_lat_p99 = std::max(max_lat_p99, s.latency_p99_us);
  }
  const double p99 = tipforce::percentile(lat, 0.99);
  // Bound: a window waits behind at most `capacity` others plus the one in progress.
  const double bound_us = (capacity + 1) * max_solve_p99 + 100'000;
  EXPECT_LT(p99, bound_us);
  EXPECT_LT(p99, 1'000'000);
  std::printf("overload: %d sent at 5000/s, received %ld, estimates %ld, dropped %ld; latency p99 %.0f us "
              "(bound %.0f us), solve p99 %.0f us\n",
              n, static_cast<long>(last.windows_received), static_cast<long>(last.windows_done),
              static_cast<long>(last.windows_dropped), p99, bound_us, max_solve_p99);
}

// ---- point 5: SIGTERM with windows queued ------------------------------------------------------

TEST(Shutdown, SigtermWithWindowsQueued) {
  if (!in_netns()) GTEST_SKIP() << "needs a network namespace (run through netns_run.sh)";
  Paths p = setup("shutdown");
  // 100 windows of 5000 samples with 8 modes, sent within ~0.1 s: far more than the solver finishes
  // before SIGTERM, so the queue (32) is full when it comes.
  const int n = 100;
  const fs::path cfg = p.dir / "c.toml", in = p.dir / "scan.lcmlog", out = p.dir / "out.lcmlog";
  write_text(cfg, test_config(32, 0.25, 8));
  ScanOptions so;
  so.windows = n;
  so.samples = 5000;
  write_log(in, make_scan(tipforce::load_config(cfg), so));
  LiveDaemon d;
  ASSERT_TRUE(d.start(p, cfg, file_url(out, "?mode=w"), {{"WATCHDOG_USEC", "200000"}},
                      std::string(kUdpmUrl) + "&recv_buf_size=4194304"))
      << read_text(p.dir / "stderr.txt");
  lcm::LCM lcm(kUdpmUrl);
  ASSERT_TRUE(lcm.good());
  for (const Event& e : read_log(in)) {
    lcm.publish(e.channel, e.data.data(), static_cast<unsigned>(e.data.size()));
    std::this_thread::sleep_for(1ms);
  }
  std::this_thread::sleep_for(250ms);  // received (watchdog pings at 100 ms meanwhile)
  auto [code, took] = d.stop();
  ASSERT_TRUE(code);
  EXPECT_EQ(*code, 0);
  EXPECT_LT(took, 2.0);
  Outputs o = read_outputs(out);
  ASSERT_FALSE(o.stats.empty());
  const auto& last = o.stats.back();
  EXPECT_EQ(last.windows_received, n);
  EXPECT_GT(last.windows_dropped, 0) << "nothing was queued at SIGTERM";
  EXPECT_EQ(static_cast<int64_t>(o.estimates.size()), last.windows_done);
  EXPECT_EQ(last.windows_done + last.windows_dropped, last.windows_received);
  EXPECT_EQ(last.queue_depth, 0);
  // systemd: READY first, watchdog pings from the loop, STOPPING at the end.
  ASSERT_FALSE(d.notifications.empty());
  EXPECT_EQ(d.notifications.front().rfind("READY=1", 0), 0u);
  EXPECT_NE(std::find(d.notifications.begin(), d.notifications.end(), "WATCHDOG=1"), d.notifications.end());
  EXPECT_NE(std::find(d.notifications.begin(), d.notifications.end(), "STOPPING=1"), d.notifications.end());
  std::printf("shutdown: exit %d after %.3f s; received %ld, estimates %ld, dropped %ld\n", *code, took,
              static_cast<long>(last.windows_received), static_cast<long>(last.windows_done),
              static_cast<long>(last.windows_dropped));
}

TEST(Shutdown, SlowWindowInProgressDoesNotHoldTheExit) {
  // No network needed: a log file holding one very long window keeps the solver busy for seconds.
  Paths p = setup("shutdown-slow");
  const fs::path cfg = p.dir / "c.toml", in = p.dir / "in.lcmlog", out = p.dir / "out.lcmlog";
  // SPEC's largest window (the default cap is lower) keeps the solver busy for seconds.
  write_text(cfg, test_config(64, 0.25, 8, "max_window_samples = 1000000"));
  ScanOptions so;
  so.windows = 3;
  so.samples = 1'000'000;
  write_log(in, make_scan(tipforce::load_config(cfg), so));
  Child c = spawn({p.tipforced, "--config", cfg.string(), "--input-url", file_url(in, "?speed=0"), "--output-url",
                   file_url(out, "?mode=w")},
                  p.dir / "stderr.txt");
  ASSERT_TRUE(wait_until([&] { return read_text(p.dir / "stderr.txt").find("started") != std::string::npos; }, 30s));
  std::this_thread::sleep_for(300ms);  // the first window is being solved
  const auto t0 = std::chrono::steady_clock::now();
  c.signal(SIGTERM);
  auto code = c.wait(10s);
  const double took = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (!code) c.kill_and_reap();
  ASSERT_TRUE(code);
  EXPECT_EQ(*code, 0) << read_text(p.dir / "stderr.txt");
  EXPECT_LT(took, 2.0);
  Outputs o = read_outputs(out);
  ASSERT_FALSE(o.stats.empty());
  const auto& last = o.stats.back();
  EXPECT_EQ(static_cast<int64_t>(o.estimates.size()), last.windows_done);
  EXPECT_EQ(last.windows_done + last.windows_dropped, last.windows_received);
  std::printf("slow window: exit %d after %.3f s; received %ld, estimates %ld, dropped %ld\n", *code, took,
              static_cast<long>(last.windows_received), static_cast<long>(last.windows_done),
              static_cast<long>(last.windows_dropped));
}

TEST(Live, TipforceSimulateScanThroughLcmLogplayerAndLogger) {
  // Point 1 with the lead's `tipforce simulate` as the source, where it is built.
  if (!in_netns()) GTEST_SKIP() << "needs a network namespace (run through netns_run.sh)";
  Paths p = setup("live-simulate");
  if (p.cli.empty() || p.logger.empty() || p.player.empty()) GTEST_SKIP() << "tipforce / lcm-logger / lcm-logplayer not built";
  const fs::path cfg = p.dir / "c.toml", scan = p.dir / "scan.toml", in = p.dir / "scan.lcmlog",
                 rec = p.dir / "recorded.lcmlog";
  write_text(cfg, test_config(64, 0.25));
  write_text(scan,
             "sample_period_s = 7.853e-7\nsamples_per_window = 1250\npixels_x = 6\npixels_y = 5\nstart = \"steady\"\n"
             "noise_m = 2e-11\nseed = 5\n[drive]\nkind = \"sine\"\namplitude_m = 0.1e-9\nfrequency_hz = 25468.9\n"
             "[truth]\nk_n_per_m = 2.5\nh_m = 12e-9\n");
  Child sim = spawn({p.cli, "simulate", "--config", cfg.string(), "--probe", "tip", "--scan", scan.string(), "--out",
                     in.string(), "--integrator", "fast"},
                    p.dir / "simulate.txt");
  auto sc = sim.wait(120s);
  ASSERT_TRUE(sc);
  ASSERT_EQ(*sc, 0) << read_text(p.dir / "simulate.txt");
  const int n = 30;
  Child logger = spawn({p.logger, "-f", std::string("--lcm-url=") + kUdpmUrl, "--channel=TIPFORCE_(ESTIMATE|STATS)",
                        rec.string()},
                       p.dir / "logger.txt");
  LiveDaemon d;
  ASSERT_TRUE(d.start(p, cfg, "")) << read_text(p.dir / "stderr.txt");
  std::this_thread::sleep_for(300ms);
  // The log is stamped in acquisition time (~1000 windows/s); a tenth of that is sustainable here.
  Child player = spawn({p.player, "--speed=0.1", std::string("--lcm-url=") + kUdpmUrl, in.string()},
                       p.dir / "player.txt");
  ASSERT_TRUE(player.wait(60s));
  EXPECT_TRUE(wait_until([&] { return count_estimates(rec) >= n; }, 60s)) << count_estimates(rec);
  std::this_thread::sleep_for(400ms);
  auto [code, took] = d.stop();
  ASSERT_TRUE(code);
  EXPECT_EQ(*code, 0);
  std::this_thread::sleep_for(300ms);
  logger.signal(SIGINT);
  ASSERT_TRUE(logger.wait(10s));
  Outputs o = read_outputs(rec);
  ASSERT_EQ(o.estimates.size(), static_cast<std::size_t>(n));
  int good = 0;
  for (const auto& e : o.estimates) {
    EXPECT_NE(e.status, force_estimate_t::STATUS_REJECTED) << e.message;
    if (std::abs(param(e, "k_n_per_m") / 2.5 - 1) < 0.05 && std::abs(param(e, "h_m") - 12e-9) < 0.5e-9) ++good;
  }
  // Accuracy on this scan is the library's business (reported, not asserted here); the daemon's is
  // to give exactly what `tipforce invert` gives for the same log.
  {
    Child inv = spawn({p.cli, "invert", "--config", cfg.string(), "--in", in.string(), "--out",
                       (p.dir / "inverted.lcmlog").string()},
                      p.dir / "invert.txt");
    auto ic = inv.wait(120s);
    ASSERT_TRUE(ic);
    ASSERT_EQ(*ic, 0) << read_text(p.dir / "invert.txt");
    Outputs ref = read_outputs(p.dir / "inverted.lcmlog");
    ASSERT_EQ(ref.estimates.size(), o.estimates.size());
    std::vector<force_estimate_t> live = o.estimates;
    std::sort(live.begin(), live.end(), [](const auto& a, const auto& b) { return a.seq < b.seq; });
    for (std::size_t i = 0; i < live.size(); ++i) {
      EXPECT_EQ(live[i].seq, ref.estimates[i].seq);
      EXPECT_EQ(live[i].params, ref.estimates[i].params) << "seq " << live[i].seq;
      EXPECT_EQ(live[i].param_sigma, ref.estimates[i].param_sigma) << "seq " << live[i].seq;
    }
  }
  ASSERT_FALSE(o.stats.empty());
  EXPECT_EQ(o.stats.back().windows_received, n);
  EXPECT_EQ(o.stats.back().windows_done, n);
  EXPECT_EQ(o.stats.back().windows_dropped, 0);
  std::printf("live (tipforce simulate): %d windows, %d within 5%% (k) and 0.5 nm (h) of the truth\n", n, good);
}
