// Unit tests of tipforced's parts: the bounded queue, the statistics, the notify protocol, the
// rate limiter.
#include <gtest/gtest.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <string>
#include <thread>

#include "bounded_queue.hpp"
#include "daemon.hpp"
#include "latency_stats.hpp"
#include "rate_limiter.hpp"
#include "sd_notify.hpp"

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
  EXPECT_DOUBLE_EQ(percentile(v, 0.5), 50);
  EXPECT_DOUBLE_EQ(percentile(v, 0.9), 90);
  EXPECT_DOUBLE_EQ(percentile(v, 0.99), 99);
  EXPECT_DOUBLE_EQ(percentile(v, 1.0), 100);
  std::vector<double> one{7};
  EXPECT_DOUBLE_EQ(percentile(one, 0.99), 7);
  std::vector<double> none;
  EXPECT_DOUBLE_EQ(percentile(none, 0.5), 0);
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
