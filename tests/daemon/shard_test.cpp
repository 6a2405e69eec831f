// Several tipforced on one window stream (issue 10 item 6, issue 12), with the real binary on udpm.
//   Foreign.*  two daemons on one channel each notice and count the other's estimates; one daemon
//              alone counts none (netns_run.sh: one private network namespace).
// Skipped when not inside the namespace the ctest entry makes (TFD_IN_NETNS).
#include <gtest/gtest.h>

#include <atomic>
#include <cstdlib>
#include <map>
#include <mutex>
#include <set>

#include <lcm/lcm-cpp.hpp>

#include "testlib.hpp"

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
  }
  lcm::LCM lcm_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
  std::mutex mutex_;
  std::vector<force_estimate_t> estimates_;
  std::map<std::string, latency_stats_t> stats_;
};

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
