// Several tipforced on one window stream (issue 10 item 6, issue 12), with the real binary on udpm.
//   Foreign.*  two daemons on one channel each notice and count the other's estimates; one daemon
//              alone counts none (netns_run.sh: one private network namespace).
//   Shard.*    issue 12's acceptance 1: two shards on two "hosts" (network namespaces joined by a
//              veth bridge, netns_hosts.sh), the acquisition on a third; every window answered
//              once, estimates bit-equal to one daemon's, stats adding up, a duplicate shard seen.
// Skipped when not inside the namespaces the ctest entries make (TFD_IN_NETNS).
#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <cstdlib>
#include <map>
#include <mutex>
#include <set>
#include <sstream>

#include <lcm/lcm-cpp.hpp>

#include "testlib.hpp"
#include "tipforce/shard.hpp"

using namespace tfdtest;
using namespace std::chrono_literals;
using tipforce::force_estimate_t;
using tipforce::latency_stats_t;

namespace {

const char* const kUdpmUrl = "udpm://239.255.76.67:7667?ttl=0";

std::string env_or_empty(const char* name) {
  const char* v = std::getenv(name);
  return v ? v : "";
}

fs::path test_dir(const std::string& name) {
  fs::path base = env_or_empty("TFD_TMP");
  if (base.empty()) base = fs::temp_directory_path() / "tipforced-tests";
  const fs::path dir = base / name;
  fs::remove_all(dir);
  fs::create_directories(dir);
  return dir;
}

// Everything on the estimate and stats channels, as a bystander on the network sees it.
class Recorder {
 public:
  Recorder(const std::string& url, std::vector<std::string> stats_channels) : lcm_(url) {
    lcm_.subscribe("TIPFORCE_ESTIMATE", &Recorder::on_estimate, this);
    for (const auto& c : stats_channels) lcm_.subscribe(c, &Recorder::on_stats, this);
    thread_ = std::thread([this] {
      while (!stop_) lcm_.handleTimeout(50);
    });
  }
  ~Recorder() {
    stop_ = true;
    thread_.join();
  }
  bool good() { return lcm_.good(); }
  std::size_t estimates() {
    std::lock_guard<std::mutex> lock(mutex_);
    return estimates_.size();
  }
  std::vector<force_estimate_t> estimate_list() {
    std::lock_guard<std::mutex> lock(mutex_);
    return estimates_;
  }
  // Every stats message seen on `channel`, in order of arrival (the last of each sender is its final).
  std::vector<latency_stats_t> stats_list(const std::string& channel) {
    std::lock_guard<std::mutex> lock(mutex_);
    return all_stats_[channel];
  }
  // The last stats message seen on `channel`.
  std::optional<latency_stats_t> last_stats(const std::string& channel) {
    std::lock_guard<std::mutex> lock(mutex_);
    auto it = stats_.find(channel);
    if (it == stats_.end()) return std::nullopt;
    return it->second;
  }

 private:
  void on_estimate(const lcm::ReceiveBuffer*, const std::string&, const force_estimate_t* m) {
    std::lock_guard<std::mutex> lock(mutex_);
    estimates_.push_back(*m);
  }
  void on_stats(const lcm::ReceiveBuffer*, const std::string& channel, const latency_stats_t* m) {
    std::lock_guard<std::mutex> lock(mutex_);
    stats_[channel] = *m;
    all_stats_[channel].push_back(*m);
  }
  lcm::LCM lcm_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
  std::mutex mutex_;
  std::vector<force_estimate_t> estimates_;
  std::map<std::string, latency_stats_t> stats_;
  std::map<std::string, std::vector<latency_stats_t>> all_stats_;
};

// test_config with its probe repeated under each name (the same cantilever and model).
std::string multi_probe_config(const std::vector<std::string>& names, const std::string& extra_daemon) {
  const std::string one = test_config(64, 0.25, 3, extra_daemon);
  const std::size_t at = one.find("[probe.tip]");
  std::string out = one.substr(0, at);
  for (const std::string& name : names) {
    std::string probe = one.substr(at);
    const std::string from = "[probe.tip", to = "[probe." + name;
    for (std::size_t pos = 0; (pos = probe.find(from, pos)) != std::string::npos; pos += to.size())
      probe.replace(pos, from.size(), to);
    out += probe;
  }
  return out;
}

struct Key {
  std::string probe;
  std::int64_t seq;
  bool operator<(const Key& o) const { return probe != o.probe ? probe < o.probe : seq < o.seq; }
};

// What an estimate says about its window, but when it was received and published: equal or not.
std::string difference(const force_estimate_t& a, const force_estimate_t& b) {
  auto same = [](double x, double y) { return x == y || (std::isnan(x) && std::isnan(y)); };
  if (a.status != b.status || a.message != b.message) return "status or message";
  if (a.param_names != b.param_names || a.params != b.params || a.param_sigma != b.param_sigma) return "parameters";
  if (!same(a.misfit, b.misfit) || !same(a.peak_force_n, b.peak_force_n) || !same(a.mean_force_n, b.mean_force_n) ||
      !same(a.max_indentation_m, b.max_indentation_m) || !same(a.dissipated_energy_j, b.dissipated_energy_j))
    return "derived quantities";
  if (a.iterations != b.iterations || a.forward_solves != b.forward_solves) return "iterations";
  return {};
}

// One tipforced in file mode over `in`: the single daemon the shards are compared with.
std::map<Key, force_estimate_t> single_daemon(const std::string& tipforced, const fs::path& dir, const fs::path& config,
                                              const fs::path& in) {
  const fs::path out = dir / "single.lcmlog";
  Child c = spawn({tipforced, "--config", config.string(), "--input-url", "file://" + in.string() + "?speed=0",
                   "--output-url", "file://" + out.string() + "?mode=w"},
                  dir / "single.txt");
  auto code = c.wait(240s);
  if (!code) c.kill_and_reap();
  EXPECT_EQ(code.value_or(-1), 0) << read_text(dir / "single.txt");
  std::map<Key, force_estimate_t> by_window;
  for (const Event& e : read_log(out)) {
    if (e.channel != "TIPFORCE_ESTIMATE") continue;
    if (auto m = decode<force_estimate_t>(e)) by_window[{m->probe, m->seq}] = *m;
  }
  return by_window;
}

// The hosts netns_hosts.sh made: "nsenter --net=..." prefixes, one per host.
std::vector<std::vector<std::string>> hosts() {
  std::vector<std::vector<std::string>> out;
  std::istringstream pids(env_or_empty("TFD_HOST_PIDS"));
  for (std::string pid; pids >> pid;) out.push_back({"nsenter", "--net=/proc/" + pid + "/ns/net"});
  return out;
}

// Multicast that crosses the bridge between the namespaces (TTL 1), and nothing further.
const char* const kLanUrl = "udpm://239.255.76.67:7667?ttl=1";

}  // namespace

// Issue 10 item 6: "two daemons on one channel answer every window twice, and nothing warns".
// Each of two daemons must count exactly the other's estimates (its own echo is not foreign, a
// copy from the other is), and warn; a daemon alone must count none although its own estimates
// come back to it through the multicast loopback.
TEST(Foreign, TwoDaemonsOnOneChannelEachCountTheOthersEstimates) {
  if (env_or_empty("TFD_IN_NETNS") != "1") GTEST_SKIP() << "needs a network namespace (run through netns_run.sh)";
  const std::string tipforced = env_or_empty("TIPFORCED");
  const fs::path dir = test_dir("foreign");
  const int n = 24;
  std::vector<std::string> channels;
  std::vector<fs::path> configs;
  for (const char* name : {"A", "B", "ALONE"}) {
    const fs::path d = dir / name;
    fs::create_directories(d);
    configs.push_back(d / "c.toml");
    channels.push_back(std::string("TIPFORCE_STATS_") + name);
    write_text(configs.back(), test_config(64, 0.25, 3, "stats_channel = \"" + channels.back() + "\""));
  }
  ScanOptions so;
  so.windows = n;
  const std::vector<Event> scan = make_scan(tipforce::load_config(configs[0]), so);
  Recorder rec(kUdpmUrl, channels);
  ASSERT_TRUE(rec.good());
  lcm::LCM acquisition(kUdpmUrl);
  ASSERT_TRUE(acquisition.good());
  auto send_scan = [&] {
    for (const Event& e : scan) {
      acquisition.publish(e.channel, e.data.data(), static_cast<unsigned>(e.data.size()));
      std::this_thread::sleep_for(20ms);
    }
  };

  // Two daemons on one channel.
  {
    LiveProcess a, b;
    ASSERT_TRUE(a.start(tipforced, dir / "A", configs[0], kUdpmUrl, "")) << read_text(dir / "A" / "stderr.txt");
    ASSERT_TRUE(b.start(tipforced, dir / "B", configs[1], kUdpmUrl, "")) << read_text(dir / "B" / "stderr.txt");
    send_scan();
    EXPECT_TRUE(wait_until([&] { return rec.estimates() >= 2u * n; }, 60s)) << rec.estimates();
    std::this_thread::sleep_for(500ms);  // the last echoes handled, one more stats period
    for (LiveProcess* d : {&a, &b}) {
      auto [code, took] = d->stop();
      ASSERT_TRUE(code);
      EXPECT_EQ(*code, 0);
    }
    std::this_thread::sleep_for(300ms);  // final stats recorded
    for (const auto& [name, d] : {std::pair<std::string, LiveProcess*>{"A", &a}, {"B", &b}}) {
      auto last = rec.last_stats("TIPFORCE_STATS_" + name);
      ASSERT_TRUE(last) << name;
      EXPECT_EQ(last->windows_received, n) << name;
      EXPECT_EQ(last->windows_done, n) << name;
      EXPECT_EQ(last->foreign_estimates, n) << name << ": the other daemon answered all " << n << " windows";
      const std::string log = read_text(d->stderr_path);
      EXPECT_NE(log.find("another publisher answered probe 'tip'"), std::string::npos) << log;
      // Rate-limited: one line per minute, not one per estimate.
      std::size_t lines = 0;
      for (std::size_t pos = 0; (pos = log.find("another publisher answered", pos)) != std::string::npos; ++pos) ++lines;
      EXPECT_EQ(lines, 1u) << log;
      std::printf("daemon %s: received %ld, estimates %ld, foreign estimates %ld\n", name.c_str(),
                  static_cast<long>(last->windows_received), static_cast<long>(last->windows_done),
                  static_cast<long>(last->foreign_estimates));
    }
    // What a bystander saw: every window answered twice.
    std::map<std::int64_t, int> answers;
    for (const auto& e : rec.estimate_list()) ++answers[e.seq];
    EXPECT_EQ(answers.size(), static_cast<std::size_t>(n));
    for (const auto& [seq, count] : answers) EXPECT_EQ(count, 2) << "seq " << seq;
  }

  // The same with the estimates on another LCM URL than the windows (the daemon then watches an
  // output LCM of its own).
  {
    const std::string out_url = "udpm://239.255.76.67:7668?ttl=0";
    Recorder out_rec(out_url, {"TIPFORCE_STATS_A", "TIPFORCE_STATS_B"});
    ASSERT_TRUE(out_rec.good());
    LiveProcess a, b;
    for (const char* name : {"A2", "B2"}) fs::create_directories(dir / name);
    ASSERT_TRUE(a.start(tipforced, dir / "A2", configs[0], kUdpmUrl, out_url)) << read_text(dir / "A2" / "stderr.txt");
    ASSERT_TRUE(b.start(tipforced, dir / "B2", configs[1], kUdpmUrl, out_url)) << read_text(dir / "B2" / "stderr.txt");
    send_scan();
    EXPECT_TRUE(wait_until([&] { return out_rec.estimates() >= 2u * n; }, 60s)) << out_rec.estimates();
    std::this_thread::sleep_for(500ms);
    for (LiveProcess* d : {&a, &b}) EXPECT_EQ(d->stop().first.value_or(-1), 0);
    std::this_thread::sleep_for(300ms);
    for (const char* name : {"A", "B"}) {
      auto last = out_rec.last_stats(std::string("TIPFORCE_STATS_") + name);
      ASSERT_TRUE(last) << name;
      EXPECT_EQ(last->windows_done, n) << name;
      EXPECT_EQ(last->foreign_estimates, n) << name << ", output on its own URL";
    }
  }

  // One daemon alone: its own estimates come back to it and none is foreign.
  {
    const std::size_t before = rec.estimates();
    LiveProcess alone;
    ASSERT_TRUE(alone.start(tipforced, dir / "ALONE", configs[2], kUdpmUrl, ""))
        << read_text(dir / "ALONE" / "stderr.txt");
    send_scan();
    EXPECT_TRUE(wait_until([&] { return rec.estimates() >= before + n; }, 60s)) << rec.estimates();
    std::this_thread::sleep_for(500ms);
    auto [code, took] = alone.stop();
    ASSERT_TRUE(code);
    EXPECT_EQ(*code, 0);
    std::this_thread::sleep_for(300ms);
    auto last = rec.last_stats("TIPFORCE_STATS_ALONE");
    ASSERT_TRUE(last);
    EXPECT_EQ(last->windows_done, n);
    EXPECT_EQ(last->foreign_estimates, 0);
    EXPECT_EQ(read_text(alone.stderr_path).find("another publisher answered"), std::string::npos);
    std::printf("daemon alone: estimates %ld, foreign estimates %ld\n", static_cast<long>(last->windows_done),
                static_cast<long>(last->foreign_estimates));
  }
}

// Issue 12, acceptance 1: two shards (count = 2, by = "probe") on two hosts, the acquisition on a
// third. Four probes, interleaved as a multi-probe instrument sends them; each shard answers its
// probes' windows and ignores the others. Then a third daemon on a third host is started with
// shard index 1 by mistake: shard 1 and it count each other's estimates, shard 0 counts none.
TEST(Shard, TwoShardsOnTwoHostsAnswerEveryWindowOnceAsOneDaemonWould) {
  if (env_or_empty("TFD_IN_NETNS") != "1") GTEST_SKIP() << "needs the namespaces of netns_hosts.sh";
  const auto lan = hosts();
  ASSERT_EQ(lan.size(), 3u) << "netns_hosts.sh 3 makes the hosts";
  const std::string tipforced = env_or_empty("TIPFORCED");
  const fs::path dir = test_dir("shard-probe");
  const std::vector<std::string> probes = {"afm1", "afm2", "afm3", "afm4"};
  const int per_probe = 12;
  const fs::path cfg = dir / "c.toml", cfg_dup = dir / "dup.toml", cfg_single = dir / "single.toml";
  write_text(cfg, multi_probe_config(probes, "shard = { count = 2, by = \"probe\" }"));
  write_text(cfg_dup, multi_probe_config(probes, "shard = { count = 2, by = \"probe\" }\nstats_channel = \"TIPFORCE_STATS_DUP\""));
  write_text(cfg_single, multi_probe_config(probes, ""));
  const tipforce::Config config = tipforce::load_config(cfg);
  // The shares, worked out independently of the daemons: FNV-1a 64 of the name, mod 2 (the
  // function itself is checked against FNV's published vectors in the unit tests).
  std::map<std::string, int> share;
  int in_share[2] = {0, 0};
  for (const auto& p : probes) {
    share[p] = static_cast<int>(tipforce::fnv1a64(p) % 2);
    in_share[share[p]] += per_probe;
  }
  ASSERT_GT(in_share[0], 0) << "these probe names all hash to shard 1: pick others";
  ASSERT_GT(in_share[1], 0) << "these probe names all hash to shard 0: pick others";
  // The stream: the probes' scans interleaved window by window.
  std::vector<std::vector<Event>> scans;
  for (std::size_t i = 0; i < probes.size(); ++i) {
    ScanOptions so;
    so.probe = probes[i];
    so.windows = per_probe;
    so.seed = 11 + i;
    scans.push_back(make_scan(config, so));
  }
  std::vector<Event> stream;
  for (int w = 0; w < per_probe; ++w)
    for (const auto& scan : scans) stream.push_back(scan[static_cast<std::size_t>(w)]);
  const int n = static_cast<int>(stream.size());
  write_log(dir / "stream.lcmlog", stream);

  Recorder rec(kLanUrl, {"TIPFORCE_STATS", "TIPFORCE_STATS_DUP"});
  ASSERT_TRUE(rec.good());
  lcm::LCM acquisition(kLanUrl);
  ASSERT_TRUE(acquisition.good());
  auto send = [&] {
    for (const Event& e : stream) {
      acquisition.publish(e.channel, e.data.data(), static_cast<unsigned>(e.data.size()));
      std::this_thread::sleep_for(15ms);
    }
  };
  std::vector<std::unique_ptr<LiveProcess>> shards;
  for (int i = 0; i < 2; ++i) {
    const fs::path d = dir / ("shard" + std::to_string(i));
    fs::create_directories(d);
    shards.push_back(std::make_unique<LiveProcess>());
    ASSERT_TRUE(shards.back()->start(tipforced, d, cfg, kLanUrl, "", {}, {"--shard-index", std::to_string(i)},
                                     lan[static_cast<std::size_t>(i)]))
        << read_text(d / "stderr.txt");
  }
  send();
  EXPECT_TRUE(wait_until([&] { return rec.estimates() >= static_cast<std::size_t>(n); }, 120s)) << rec.estimates();
  std::this_thread::sleep_for(500ms);  // anything late would show as a second answer

  // Every window answered exactly once, by the shard it belongs to, as one daemon answers it.
  const auto first = rec.estimate_list();
  std::map<Key, std::vector<force_estimate_t>> answers;
  for (const auto& e : first) answers[{e.probe, e.seq}].push_back(e);
  EXPECT_EQ(answers.size(), static_cast<std::size_t>(n));
  const auto single = single_daemon(tipforced, dir, cfg_single, dir / "stream.lcmlog");
  ASSERT_EQ(single.size(), static_cast<std::size_t>(n));
  int once = 0, equal = 0;
  for (const auto& [key, list] : answers) {
    EXPECT_EQ(list.size(), 1u) << key.probe << " seq " << key.seq << " answered " << list.size() << " times";
    if (list.size() != 1) continue;
    ++once;
    const std::string d = difference(list[0], single.at(key));
    EXPECT_EQ(d, "") << key.probe << " seq " << key.seq << ": differs from the single daemon's estimate";
    equal += d.empty();
  }

  // A third daemon, started with shard index 1 by mistake, on the third host; the stream again.
  const std::size_t before = rec.estimates();
  {
    fs::create_directories(dir / "dup");
    LiveProcess dup;
    ASSERT_TRUE(dup.start(tipforced, dir / "dup", cfg_dup, kLanUrl, "", {}, {"--shard-index", "1"}, lan[2]))
        << read_text(dir / "dup" / "stderr.txt");
    send();
    EXPECT_TRUE(wait_until([&] { return rec.estimates() >= before + n + in_share[1]; }, 120s)) << rec.estimates();
    std::this_thread::sleep_for(500ms);
    auto [code, took] = dup.stop();
    EXPECT_EQ(code.value_or(-1), 0);
    std::this_thread::sleep_for(300ms);
    auto last = rec.last_stats("TIPFORCE_STATS_DUP");
    ASSERT_TRUE(last);
    EXPECT_EQ(last->shard_index, 1);
    EXPECT_EQ(last->windows_done, in_share[1]);
    EXPECT_EQ(last->foreign_estimates, in_share[1]) << "shard 1 answered every window of the share";
    EXPECT_NE(read_text(dup.stderr_path).find("one shard index used twice"), std::string::npos);
    std::printf("duplicate shard 1: estimates %ld, foreign estimates %ld\n", static_cast<long>(last->windows_done),
                static_cast<long>(last->foreign_estimates));
  }
  for (auto& s : shards) {
    auto [code, took] = s->stop();
    EXPECT_EQ(code.value_or(-1), 0);
  }
  std::this_thread::sleep_for(300ms);

  // The shards' final stats: named, adding up to the windows sent (twice over: two rounds).
  std::map<int, latency_stats_t> final_stats;
  for (const auto& e : rec.stats_list("TIPFORCE_STATS")) final_stats[e.shard_index] = e;
  ASSERT_EQ(final_stats.size(), 2u);
  std::int64_t done = 0;
  for (int i = 0; i < 2; ++i) {
    const latency_stats_t& s = final_stats.at(i);
    EXPECT_EQ(s.shard_count, 2);
    EXPECT_EQ(s.windows_received, 2 * n) << "shard " << i << ": every window reaches every shard";
    EXPECT_EQ(s.windows_done, 2 * in_share[i]) << "shard " << i;
    EXPECT_EQ(s.windows_other_shards, 2 * (n - in_share[i])) << "shard " << i;
    EXPECT_EQ(s.windows_dropped, 0) << "shard " << i;
    EXPECT_EQ(s.windows_done + s.windows_dropped + s.windows_other_shards, s.windows_received) << "shard " << i;
    done += s.windows_done;
    std::printf("shard %d/%d: received %ld, estimates %ld, other shards' windows %ld, dropped %ld, foreign estimates "
                "%ld\n",
                s.shard_index, s.shard_count, static_cast<long>(s.windows_received), static_cast<long>(s.windows_done),
                static_cast<long>(s.windows_other_shards), static_cast<long>(s.windows_dropped),
                static_cast<long>(s.foreign_estimates));
  }
  EXPECT_EQ(done, 2 * n) << "the shards' estimates add up to the windows sent";
  EXPECT_EQ(final_stats.at(0).foreign_estimates, 0) << "nobody else answers shard 0's windows";
  EXPECT_EQ(final_stats.at(1).foreign_estimates, in_share[1]) << "the duplicate answered shard 1's second round";
  std::printf("%d windows of %zu probes: %d answered once, %d bit-equal to the single daemon's\n", n, probes.size(),
              once, equal);
}

// by = "line": one probe's scan split by scan line, each line starting UNKNOWN (as an acquisition
// marks the pixel after its retrace). Every window is answered once and the stats add up as
// above; and since a cold start depends on its window alone (issue 9: no warm start from the
// previous line, a random search seeded by the window itself), every estimate is one daemon's,
// bit for bit: a shard's line starts as the single daemon's does, and continues as it does.
// daemon.cpu_threads is the same in every run.
TEST(Shard, ByLineEveryWindowOnceAndEveryEstimateAsOneDaemon) {
  if (env_or_empty("TFD_IN_NETNS") != "1") GTEST_SKIP() << "needs the namespaces of netns_hosts.sh";
  const auto lan = hosts();
  ASSERT_GE(lan.size(), 2u);
  const std::string tipforced = env_or_empty("TIPFORCED");
  const fs::path dir = test_dir("shard-line");
  const fs::path cfg = dir / "c.toml", cfg_single = dir / "single.toml";
  write_text(cfg, test_config(64, 0.25, 3, "shard = { count = 2, by = \"line\" }\ncpu_threads = 1"));
  write_text(cfg_single, test_config(64, 0.25, 3, "cpu_threads = 1"));
  ScanOptions so;
  so.windows = 60;  // 6 lines of 10
  so.line_starts_unknown = true;
  std::vector<TruthRow> truth;
  const std::vector<Event> stream = make_scan(tipforce::load_config(cfg), so, &truth);
  const int n = static_cast<int>(stream.size());
  write_log(dir / "stream.lcmlog", stream);
  Recorder rec(kLanUrl, {"TIPFORCE_STATS"});
  ASSERT_TRUE(rec.good());
  lcm::LCM acquisition(kLanUrl);
  ASSERT_TRUE(acquisition.good());
  std::vector<std::unique_ptr<LiveProcess>> shards;
  for (int i = 0; i < 2; ++i) {
    const fs::path d = dir / ("shard" + std::to_string(i));
    fs::create_directories(d);
    shards.push_back(std::make_unique<LiveProcess>());
    ASSERT_TRUE(shards.back()->start(tipforced, d, cfg, kLanUrl, "", {}, {"--shard-index", std::to_string(i)},
                                     lan[static_cast<std::size_t>(i)]))
        << read_text(d / "stderr.txt");
  }
  for (const Event& e : stream) {
    acquisition.publish(e.channel, e.data.data(), static_cast<unsigned>(e.data.size()));
    std::this_thread::sleep_for(15ms);
  }
  EXPECT_TRUE(wait_until([&] { return rec.estimates() >= static_cast<std::size_t>(n); }, 120s)) << rec.estimates();
  std::this_thread::sleep_for(500ms);
  for (auto& s : shards) EXPECT_EQ(s->stop().first.value_or(-1), 0);
  std::this_thread::sleep_for(300ms);

  std::map<std::int64_t, std::vector<force_estimate_t>> answers;
  for (const auto& e : rec.estimate_list()) answers[e.seq].push_back(e);
  EXPECT_EQ(answers.size(), static_cast<std::size_t>(n));
  std::map<int, latency_stats_t> final_stats;
  for (const auto& e : rec.stats_list("TIPFORCE_STATS")) final_stats[e.shard_index] = e;
  ASSERT_EQ(final_stats.size(), 2u);
  for (int i = 0; i < 2; ++i) {
    const latency_stats_t& s = final_stats.at(i);
    EXPECT_EQ(s.windows_received, n);
    EXPECT_EQ(s.windows_done, n / 2) << "shard " << i << ": three lines of ten";
    EXPECT_EQ(s.windows_other_shards, n / 2) << "shard " << i;
    EXPECT_EQ(s.windows_dropped, 0);
  }
  const auto single = single_daemon(tipforced, dir, cfg_single, dir / "stream.lcmlog");
  ASSERT_EQ(single.size(), static_cast<std::size_t>(n));
  int equal = 0;
  for (const auto& [seq, list] : answers) {
    EXPECT_EQ(list.size(), 1u) << "seq " << seq << " answered " << list.size() << " times";
    const force_estimate_t& e = list[0];
    EXPECT_EQ(e.pixel_y, truth[static_cast<std::size_t>(seq)].pixel_y);
    const std::string d = difference(e, single.at({"tip", seq}));
    EXPECT_EQ(d, "") << "seq " << seq << " (line " << e.pixel_y << "): differs from the single daemon's estimate";
    equal += d.empty();
  }
  std::printf("by line: %d windows, each answered once; %d bit-equal to one daemon's\n", n, equal);
}
