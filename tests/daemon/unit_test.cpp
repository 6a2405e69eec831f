// Unit tests of tipforced's parts: the bounded queue, the statistics, the notify protocol, the
// rate limiter.
#include <gtest/gtest.h>
#include <fcntl.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <thread>

#include "bounded_queue.hpp"
#include "daemon.hpp"
#include "latency_stats.hpp"
#include "tipforce/percentile.hpp"
#include "own_estimates.hpp"
#include "rate_limiter.hpp"
#include "sd_notify.hpp"
#include "testlib.hpp"
#include "tipforce/lcm_convert.hpp"
#include "tipforce/shard.hpp"

using namespace tipforce::daemon;

TEST(BoundedQueue, DropsTheOldestWhenFull) {
  BoundedQueue<int> q(3);
  EXPECT_FALSE(q.push(1));
  EXPECT_FALSE(q.push(2));
  EXPECT_FALSE(q.push(3));
  EXPECT_TRUE(q.full());
  auto dropped = q.push(4);
  ASSERT_TRUE(dropped);
  EXPECT_EQ(*dropped, 1);
  EXPECT_EQ(q.size(), 3u);
  EXPECT_EQ(*q.pop(), 2);
  EXPECT_EQ(*q.pop(), 3);
  EXPECT_EQ(*q.pop(), 4);
}

TEST(BoundedQueue, TryPushRefusesWhenFull) {
  BoundedQueue<int> q(1);
  int a = 1, b = 2;
  EXPECT_TRUE(q.try_push(a));
  EXPECT_FALSE(q.try_push(b));
  EXPECT_EQ(b, 2);
  EXPECT_EQ(*q.pop(), 1);
}

TEST(BoundedQueue, CloseLetsTheConsumerFinishThenStop) {
  BoundedQueue<int> q(4);
  q.push(1);
  q.push(2);
  q.close();
  EXPECT_TRUE(q.push(3));  // refused, handed back
  EXPECT_EQ(*q.pop(), 1);
  EXPECT_EQ(*q.pop(), 2);
  EXPECT_FALSE(q.pop());
}

TEST(BoundedQueue, CloseAndTakeWakesABlockedConsumer) {
  BoundedQueue<int> q(4);
  std::optional<int> got = 42;
  std::thread consumer([&] { got = q.pop(); });
  std::this_thread::sleep_for(std::chrono::milliseconds(20));
  auto left = q.close_and_take();
  consumer.join();
  EXPECT_TRUE(left.empty());
  EXPECT_FALSE(got);
}

TEST(BoundedQueue, CloseAndTakeReturnsWhatWaits) {
  BoundedQueue<int> q(4);
  q.push(1);
  q.push(2);
  auto left = q.close_and_take();
  EXPECT_EQ(left, (std::vector<int>{1, 2}));
  EXPECT_FALSE(q.pop());
}

TEST(LatencyStats, PercentilesByNearestRank) {
  std::vector<double> v;
  for (int i = 100; i >= 1; --i) v.push_back(i);
  EXPECT_DOUBLE_EQ(tipforce::percentile(v, 0.5), 50);
  EXPECT_DOUBLE_EQ(tipforce::percentile(v, 0.9), 90);
  EXPECT_DOUBLE_EQ(tipforce::percentile(v, 0.99), 99);
  EXPECT_DOUBLE_EQ(tipforce::percentile(v, 1.0), 100);
  std::vector<double> one{7};
  EXPECT_DOUBLE_EQ(tipforce::percentile(one, 0.99), 7);
  std::vector<double> none;
  EXPECT_TRUE(std::isnan(tipforce::percentile(none, 0.5)));
}

TEST(LatencyStats, CountersAreCumulativeAndPercentilesPerPeriod) {
  LatencyStats s;
  for (int i = 0; i < 5; ++i) s.on_received();
  s.on_done(1000, 400, false);
  s.on_done(3000, 500, true);
  s.on_dropped(2);
  s.on_unattributable();
  auto m = s.take_period(123, "cpu: test", 0.5, 1);
  EXPECT_EQ(m.utime, 123);
  EXPECT_EQ(m.backend, "cpu: test");
  EXPECT_EQ(m.windows_received, 5);
  EXPECT_EQ(m.windows_done, 2);
  EXPECT_EQ(m.windows_dropped, 2);
  EXPECT_EQ(m.windows_rejected, 2);  // one rejected estimate + one unattributable
  EXPECT_EQ(m.queue_depth, 1);
  EXPECT_DOUBLE_EQ(m.latency_p50_us, 1000);
  EXPECT_DOUBLE_EQ(m.latency_max_us, 3000);
  EXPECT_DOUBLE_EQ(m.solve_p99_us, 500);
  EXPECT_DOUBLE_EQ(m.windows_per_s, 4.0);
  auto next = s.take_period(456, "cpu: test", 1.0, 0);
  EXPECT_EQ(next.windows_done, 2);  // cumulative
  EXPECT_DOUBLE_EQ(next.latency_max_us, 0);
  EXPECT_DOUBLE_EQ(next.windows_per_s, 0);
}

// The run-wide figures tipforced logs when it stops: across periods, within 1 % above the nearest
// rank of every latency (tipforce::percentile over the same values), the max exact.
TEST(LatencyStats, RunLatencyCoversEveryPeriodToOnePercent) {
  LatencyStats s;
  EXPECT_EQ(s.run_latency().count, 0);
  std::vector<double> all;
  std::mt19937_64 rng(3);
  std::lognormal_distribution<double> latency(std::log(500.0), 1.0);  // us, p99 ~5 ms
  for (int period = 0; period < 4; ++period) {
    for (int i = 0; i < 2500; ++i) {
      const double us = period == 3 && i == 0 ? 0.0 : latency(rng);
      all.push_back(us);
      s.on_done(us, us / 2, false);
    }
    s.take_period(period, "cpu: test", 1.0, 0);
  }
  s.on_done(2.5e8, 1.0, false);  // 250 s: past the last bucket's start
  all.push_back(2.5e8);
  const LatencyStats::RunLatency run = s.run_latency();
  EXPECT_EQ(run.count, 10001);
  for (auto [q, got] : {std::pair{0.5, run.p50_us}, std::pair{0.99, run.p99_us}}) {
    const double want = tipforce::percentile(all, q);
    EXPECT_GE(got, want * (1 - 1e-12)) << "q " << q;
    EXPECT_LE(got, want * 1.01) << "q " << q;
  }
  EXPECT_DOUBLE_EQ(run.max_us, 2.5e8);
  // One estimate: each figure is it.
  LatencyStats one;
  one.on_done(1234.5, 1000, false);
  EXPECT_DOUBLE_EQ(one.run_latency().p99_us, 1234.5);
}

namespace {
// A datagram socket standing in for systemd's notify socket.
struct NotifySocket {
  int fd = -1;
  std::string path;
  explicit NotifySocket(const std::string& p) : path(p) {
    ::unlink(path.c_str());
    fd = ::socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    sockaddr_un a{};
    a.sun_family = AF_UNIX;
    std::snprintf(a.sun_path, sizeof(a.sun_path), "%s", path.c_str());
    if (::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof(a)) != 0) ADD_FAILURE() << "bind " << path;
    timeval tv{1, 0};
    ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof(tv));
  }
  ~NotifySocket() {
    ::close(fd);
    ::unlink(path.c_str());
  }
  std::string receive() {
    char buf[512];
    const ssize_t n = ::recv(fd, buf, sizeof(buf), 0);
    return n > 0 ? std::string(buf, static_cast<std::size_t>(n)) : std::string();
  }
};
}  // namespace

TEST(SdNotify, SendsToTheNotifySocket) {
  NotifySocket sock((std::filesystem::temp_directory_path() / ("tfd-notify-" + std::to_string(::getpid()))).string());
  ::setenv("NOTIFY_SOCKET", sock.path.c_str(), 1);
  EXPECT_TRUE(sd_notify("READY=1"));
  EXPECT_EQ(sock.receive(), "READY=1");
  ::unsetenv("NOTIFY_SOCKET");
  EXPECT_FALSE(sd_notify("READY=1"));
}

TEST(SdNotify, AFullSocketDoesNotBlockTheCaller) {
  // A manager that does not read: the datagram queue fills (net.unix.max_dgram_qlen, 10 by
  // default), after which a blocking send would hang tipforced's IO thread, SIGTERM and all.
  NotifySocket sock((std::filesystem::temp_directory_path() / ("tfd-notify-full-" + std::to_string(::getpid()))).string());
  ::setenv("NOTIFY_SOCKET", sock.path.c_str(), 1);
  int delivered = 0;
  const auto t0 = std::chrono::steady_clock::now();
  std::thread sender([&] {
    for (int i = 0; i < 1000; ++i) delivered += sd_notify("WATCHDOG=1") ? 1 : 0;
  });
  sender.join();
  const double took = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  ::unsetenv("NOTIFY_SOCKET");
  EXPECT_LT(took, 5.0);
  EXPECT_GT(delivered, 0);
  EXPECT_LT(delivered, 1000) << "the queue never filled: this test shows nothing";
  EXPECT_EQ(sock.receive(), "WATCHDOG=1") << "what was queued is still there";
}

TEST(SdNotify, WatchdogInterval) {
  ::unsetenv("WATCHDOG_USEC");
  ::unsetenv("WATCHDOG_PID");
  EXPECT_FALSE(sd_watchdog_interval());
  ::setenv("WATCHDOG_USEC", "10000000", 1);
  ASSERT_TRUE(sd_watchdog_interval());
  EXPECT_EQ(sd_watchdog_interval()->count(), 10000000);
  ::setenv("WATCHDOG_PID", std::to_string(::getpid()).c_str(), 1);
  EXPECT_TRUE(sd_watchdog_interval());
  ::setenv("WATCHDOG_PID", "1", 1);  // meant for another process
  EXPECT_FALSE(sd_watchdog_interval());
  ::unsetenv("WATCHDOG_USEC");
  ::unsetenv("WATCHDOG_PID");
}

TEST(RateLimiter, LetsABurstThroughThenCountsWhatItHoldsBack) {
  RateLimiter r(2, std::chrono::seconds(10));
  const auto t0 = RateLimiter::Clock::now();
  EXPECT_TRUE(r.allow(t0));
  EXPECT_TRUE(r.allow(t0));
  EXPECT_FALSE(r.allow(t0));
  EXPECT_FALSE(r.allow(t0 + std::chrono::seconds(1)));
  EXPECT_TRUE(r.allow(t0 + std::chrono::seconds(11)));
  EXPECT_EQ(r.take_suppressed(), 2);
  EXPECT_EQ(r.take_suppressed(), 0);
}

TEST(Urls, FileUrls) {
  EXPECT_TRUE(is_file_url("file:///tmp/x.lcmlog?speed=0"));
  EXPECT_FALSE(is_file_url("udpm://239.255.76.67:7667?ttl=0"));
  EXPECT_FALSE(is_file_url(""));
}

// ---- issue 10: URLs checked as files, and the log reader that survives damage -------------------

namespace {
std::filesystem::path fresh_dir(const std::string& name) {
  auto d = std::filesystem::temp_directory_path() / ("tipforced-unit-" + name + "-" + std::to_string(::getpid()));
  std::filesystem::remove_all(d);
  std::filesystem::create_directories(d);
  return d;
}
std::string error_of(const std::string& in, const std::string& out) {
  try {
    check_urls("c.toml", in, out);
  } catch (const StartupError& e) {
    return e.what();
  }
  return "";
}
}  // namespace

TEST(Urls, OutputIsComparedWithTheInputAsAFile) {
  const auto d = fresh_dir("urls");
  const auto in = d / "in.lcmlog";
  { std::ofstream(in) << "x"; }
  std::filesystem::create_symlink(in, d / "link.lcmlog");
  const std::string in_url = "file://" + in.string() + "?speed=0";
  EXPECT_NE(error_of(in_url, "file://" + in.string() + "?mode=w").find("(the same file)"), std::string::npos);
  EXPECT_NE(error_of(in_url, "file://" + (d / "link.lcmlog").string() + "?mode=w").find("the same file"),
            std::string::npos);
  EXPECT_NE(error_of(in_url, "file://" + (d / "." / "in.lcmlog").string() + "?mode=a").find("the same file"),
            std::string::npos);
  // A new file through a symlinked directory that leads back to the input's directory.
  std::filesystem::create_directory_symlink(d, d / "again");
  EXPECT_NE(error_of(in_url, "file://" + (d / "again" / "in.lcmlog").string() + "?mode=w").find("the same file"),
            std::string::npos);
  EXPECT_EQ(error_of(in_url, "file://" + (d / "out.lcmlog").string() + "?mode=w"), "");
  EXPECT_EQ(error_of("memq://", "file://" + in.string() + "?mode=w"), "");
  std::filesystem::remove_all(d);
}

TEST(Urls, ModesAndOptionsAreChecked) {
  const std::string out = "file:///tmp/never-written.lcmlog?mode=w";
  EXPECT_NE(error_of("file:///tmp/in.lcmlog?speed=0&mode=w", out).find("daemon.input_url: mode=w"), std::string::npos);
  EXPECT_NE(error_of("file:///tmp/in.lcmlog?sped=0", out).find("unknown option \"sped\""), std::string::npos);
  EXPECT_NE(error_of("file:///tmp/in.lcmlog?speed=-1", out).find("speed must be a number >= 0"), std::string::npos);
  EXPECT_NE(error_of("file:///tmp/in.lcmlog", "file:///tmp/out.lcmlog").find("needs mode=w"), std::string::npos);
  EXPECT_NE(error_of("file:///tmp/in.lcmlog", "file:///tmp/out.lcmlog?mode=r").find("needs mode=w"),
            std::string::npos);
  EXPECT_EQ(error_of("file:///tmp/in.lcmlog?speed=0&mode=r&start_timestamp=5", out), "");
  EXPECT_FALSE(std::filesystem::exists("/tmp/never-written.lcmlog"));
}

TEST(EventLog, RoundTripsAndResyncsPastDamage) {
  const auto d = fresh_dir("eventlog");
  const auto path = d / "log.lcmlog";
  {
    tipforce::lcmio::LogWriter w(path, false);
    for (int i = 0; i < 5; ++i) {
      const std::string data(100 + i, static_cast<char>('a' + i));
      ASSERT_TRUE(w.write("CH", 1000 + i, data.data(), data.size()));
    }
    ASSERT_TRUE(w.close());
  }
  auto read_all = [&](std::int64_t* damaged) {
    tipforce::lcmio::LogReader r(path);
    std::string seen;
    while (auto e = r.next()) seen += static_cast<char>(e->data.at(0));
    *damaged = r.damaged_stretches();
    EXPECT_EQ(r.error(), "");
    return seen;
  };
  std::int64_t damaged = 0;
  EXPECT_EQ(read_all(&damaged), "abcde");
  EXPECT_EQ(damaged, 0);
  // Event c (offset 2 * 28 + 2 * 2 + 100 + 101 = 261): a channel length of 0x40000001.
  {
    std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(261 + 20);
    f.put('\x40');
  }
  EXPECT_EQ(read_all(&damaged), "abde");
  EXPECT_EQ(damaged, 1);
  // Garbage appended, with a stray sync word in it, then a truncated event.
  {
    std::ofstream f(path, std::ios::app | std::ios::binary);
    f << "garbage\xED\xA1\xDA\x01zzz";
  }
  EXPECT_EQ(read_all(&damaged), "abde");
  EXPECT_EQ(damaged, 2);
  std::filesystem::remove_all(d);
}

TEST(EventLog, WriteErrorIsReportedAtTheEvent) {
  tipforce::lcmio::LogWriter w("/dev/full", false);
  const std::string data(10, 'x');
  EXPECT_FALSE(w.write("CH", 1, data.data(), data.size()));
  EXPECT_NE(w.error().find("No space left on device"), std::string::npos) << w.error();
  EXPECT_FALSE(w.close());
}

TEST(EventLog, WriterRefusesTheInputItselfBeforeTruncating) {
  const auto d = fresh_dir("writer-input");
  const auto path = d / "in.lcmlog";
  {
    tipforce::lcmio::LogWriter w(path, false);
    ASSERT_TRUE(w.write("CH", 1, "abc", 3));
  }
  const auto size = std::filesystem::file_size(path);
  tipforce::lcmio::LogReader reader(path);
  // Whatever path leads there (here: /proc/self/fd, which no path comparison would catch).
  const int fd = ::open(path.c_str(), O_RDONLY);
  ASSERT_GE(fd, 0);
  const std::string via_proc = "/proc/self/fd/" + std::to_string(fd);
  EXPECT_THROW(tipforce::lcmio::LogWriter(via_proc, false, &reader.identity()), tipforce::lcmio::LogError);
  EXPECT_EQ(std::filesystem::file_size(path), size);
  ::close(fd);
  std::filesystem::remove_all(d);
}

TEST(OwnEstimates, TheFirstCopyOfWhatWasPublishedIsTheEchoAnyOtherIsForeign) {
  OwnEstimates own;
  const auto t0 = OwnEstimates::Clock::time_point{} + std::chrono::hours(1);
  own.published(11, t0);
  own.published(22, t0);
  EXPECT_FALSE(own.take_echo(33, t0)) << "never published here";
  EXPECT_TRUE(own.take_echo(22, t0));
  EXPECT_FALSE(own.take_echo(22, t0)) << "a second copy of the same bytes came from someone else";
  EXPECT_TRUE(own.take_echo(11, t0));
  EXPECT_EQ(own.outstanding(), 0u);
}

TEST(OwnEstimates, MemoryIsBoundedInTimeAndCount) {
  const auto t0 = OwnEstimates::Clock::time_point{} + std::chrono::hours(1);
  OwnEstimates own(std::chrono::seconds(30), 3);
  own.published(1, t0);
  own.published(2, t0 + std::chrono::seconds(20));
  // 1 is 31 s old: forgotten (its echo never came); 2 is kept.
  EXPECT_FALSE(own.take_echo(1, t0 + std::chrono::seconds(31)));
  EXPECT_TRUE(own.take_echo(2, t0 + std::chrono::seconds(31)));
  for (std::uint64_t d = 10; d < 14; ++d) own.published(d, t0 + std::chrono::seconds(40));
  EXPECT_EQ(own.outstanding(), 3u);
  EXPECT_FALSE(own.take_echo(10, t0 + std::chrono::seconds(40))) << "the oldest of four, past the cap of three";
  EXPECT_TRUE(own.take_echo(13, t0 + std::chrono::seconds(40)));
}

TEST(Shard, Fnv1a64MatchesThePublishedTestVectors) {
  // From the FNV reference (Fowler, Noll, Vo; IETF draft-eastlake-fnv): 64-bit FNV-1a.
  EXPECT_EQ(tipforce::fnv1a64(""), 0xcbf29ce484222325ull);
  EXPECT_EQ(tipforce::fnv1a64("a"), 0xaf63dc4c8601ec8cull);
  EXPECT_EQ(tipforce::fnv1a64("foobar"), 0x85944171f73967e8ull);
}

TEST(Shard, ProbesByHashLinesByModulo) {
  using tipforce::ShardBy;
  using tipforce::ShardSpec;
  const ShardSpec one;
  EXPECT_EQ(one.shard_of("anything", 12345), 0);
  const ShardSpec by_probe{1, 3, ShardBy::probe};
  // The share is the published hash reduced mod count, whatever the platform.
  EXPECT_EQ(by_probe.shard_of("a", 7), static_cast<int>(0xaf63dc4c8601ec8cull % 3));
  EXPECT_EQ(by_probe.shard_of("foobar", 7), static_cast<int>(0x85944171f73967e8ull % 3));
  EXPECT_EQ(by_probe.shard_of("a", 7), by_probe.shard_of("a", -99)) << "the line plays no part";
  const ShardSpec by_line{0, 2, ShardBy::line};
  EXPECT_EQ(by_line.shard_of("x", 0), 0);
  EXPECT_EQ(by_line.shard_of("x", 1), 1);
  EXPECT_EQ(by_line.shard_of("y", 4), 0);
  EXPECT_EQ(by_line.shard_of("y", -1), 1) << "negative lines are lines too";
  EXPECT_TRUE(by_line.owns("z", 6));
  EXPECT_FALSE(by_line.owns("z", 7));
  EXPECT_EQ(tipforce::shard_problem({2, 2, ShardBy::line}), "shard index must be in [0, count - 1] = [0, 1], got 2");
  EXPECT_NE(tipforce::shard_problem({0, 0, ShardBy::line}), "");
  EXPECT_EQ(tipforce::shard_problem({1, 2, ShardBy::probe}), "");
}

TEST(WireHeader, WindowAndEstimateHeadersAreReadWithoutTheArrays) {
  using namespace tipforce::lcmio;
  tipforce::deflection_window_t w = tfdtest::small_window("afm7", 41);
  w.pixel_x = 3;
  w.pixel_y = -2;
  const auto bytes = tfdtest::encode(w);
  auto h = decode_window_header(bytes.data(), bytes.size());
  ASSERT_TRUE(h);
  EXPECT_EQ(h->probe, "afm7");
  EXPECT_EQ(h->seq, 41);
  EXPECT_EQ(h->pixel_x, 3);
  EXPECT_EQ(h->pixel_y, -2);
  EXPECT_FALSE(decode_estimate_header(bytes.data(), bytes.size())) << "a window is not an estimate";
  // Only the header needs to be there: a window cut after it still names itself.
  EXPECT_TRUE(decode_window_header(bytes.data(), 8 + 8 + 4 + 5 + 8 + 4 + 4));
  EXPECT_FALSE(decode_window_header(bytes.data(), 8 + 8 + 4 + 5 + 8 + 4 + 3));
  // A refused name comes back as it is answered: escaped.
  const auto bad = tfdtest::encode(tfdtest::small_window("a\nb\x1b", 1));
  h = decode_window_header(bad.data(), bad.size());
  ASSERT_TRUE(h);
  EXPECT_EQ(h->probe, "a\\x0ab\\x1b");

  tipforce::force_estimate_t e{};
  e.probe = "afm7";
  e.seq = 9;
  e.pixel_y = 5;
  e.n_params = 1;
  e.param_names = {"k_n_per_m"};
  e.params = {1.0};
  e.param_sigma = {0.1};
  const auto eb = tfdtest::encode(e);
  auto eh = decode_estimate_header(eb.data(), eb.size());
  ASSERT_TRUE(eh);
  EXPECT_EQ(eh->probe, "afm7");
  EXPECT_EQ(eh->seq, 9);
  EXPECT_EQ(eh->pixel_y, 5);
  EXPECT_FALSE(decode_window_header(eb.data(), eb.size()));
  const std::string garbage(100, '\xff');
  EXPECT_FALSE(decode_estimate_header(garbage.data(), garbage.size()));
  EXPECT_FALSE(decode_estimate_header(nullptr, 0));
}
