#pragma once
// Support for tipforced's tests and benchmark: synthetic scans, LCM log files, child processes.
#include <sys/types.h>

#include <atomic>
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "tipforce/config.hpp"
#include "tipforce/deflection_window_t.hpp"
#include "tipforce/force_estimate_t.hpp"
#include "tipforce/latency_stats_t.hpp"

namespace tfdtest {

namespace fs = std::filesystem;

// A probe and daemon section good for tests: the paper's cantilever, `modes` modes, spring model
// with k and h unknown, a small swarm (fast on a loaded 2-core machine).
std::string test_config(int queue_capacity = 64, double stats_period_s = 0.25, int modes = 3,
                        const std::string& extra_daemon = "");

struct Event {
  std::string channel;
  std::int64_t timestamp = 0;
  std::vector<std::uint8_t> data;
};

template <typename Msg>
std::vector<std::uint8_t> encode(const Msg& m) {
  std::vector<std::uint8_t> out(static_cast<std::size_t>(m.getEncodedSize()));
  m.encode(out.data(), 0, static_cast<int>(out.size()));
  return out;
}
template <typename Msg>
std::optional<Msg> decode(const Event& e) {
  Msg m;
  if (m.decode(e.data.data(), 0, static_cast<int>(e.data.size())) < 0) return std::nullopt;
  return m;
}

void write_log(const fs::path& path, const std::vector<Event>& events);
std::vector<Event> read_log(const fs::path& path);

struct ScanOptions {
  std::string probe = "tip";
  std::string channel = "TIPFORCE_WINDOW";
  int windows = 20;
  int samples = 1250;
  int samples_per_period = 50;
  double drive_amplitude_m = 0.1e-9;
  double noise_m = 2e-11;
  std::uint64_t seed = 7;
  double spacing_s = 0.002;  // log timestamps (replay rate at speed 1)
  int width = 10;            // pixels per scan line
  // Each line's first window INITIAL_UNKNOWN, as an acquisition marks the pixel after its retrace
  // (the data stay one contiguous trajectory); otherwise only window 0 is.
  bool line_starts_unknown = false;
  // Every this many windows (0: never) a false continuation: the window is marked CONTINUED but
  // its trajectory starts afresh, from the drive's steady state (as after an unreported restart).
  int false_continuation_every = 0;
  // What the pixels hold. smooth: k 1-4 N/m and h varying as sines of the pixel (k by up to 30 %
  // from one pixel to the next). domains: issue 9's 1 MHz scan line as tipforce bench inverts it
  // (cmd_bench.cpp): k in domains of 1 and 4 N/m (16 pixels each), h 20-26 nm rising in 2 nm steps
  // every 24 pixels, a 2 nm drive at 25.6 kHz sampled at 1e-6 s.
  enum class Pattern { smooth, domains } pattern = Pattern::smooth;
};

struct TruthRow {
  std::int64_t seq = 0;
  int pixel_x = 0, pixel_y = 0;
  std::map<std::string, double> values;  // the probe's unknowns
};

// A continuous scan: window 0 starts from the drive's steady state (INITIAL_UNKNOWN), each later
// window continues the previous one (INITIAL_CONTINUED; with line_starts_unknown, a line's first
// window is UNKNOWN); k and h vary smoothly across pixels.
// Simulated with the library's forward solver plus Gaussian noise.
std::vector<Event> make_scan(const tipforce::Config& config, const ScanOptions& options,
                             std::vector<TruthRow>* truth = nullptr);
void write_truth_csv(const fs::path& path, const std::vector<TruthRow>& truth);

// A minimal good window (for plumbing tests), and its message.
tipforce::deflection_window_t small_window(const std::string& probe, std::int64_t seq, int samples = 400);

// Child processes.
struct Child {
  pid_t pid = -1;
  // Waits up to `timeout` for the exit; the exit code (128+signal when killed), nullopt on timeout.
  std::optional<int> wait(std::chrono::milliseconds timeout);
  void signal(int signo) const;
  // Kills (SIGKILL) and reaps if still running.
  void kill_and_reap();
};
// Starts argv[0] with stdout and stderr appended to `log` (or inherited when empty).
Child spawn(const std::vector<std::string>& argv, const fs::path& log = {},
            const std::map<std::string, std::string>& env = {});

// A datagram socket standing in for systemd's $NOTIFY_SOCKET.
class NotifyListener {
 public:
  explicit NotifyListener(fs::path path);
  ~NotifyListener();
  const fs::path& path() const { return path_; }
  // The next datagram, or "" after `timeout`.
  std::string receive(std::chrono::milliseconds timeout);

 private:
  fs::path path_;
  int fd_ = -1;
};

// tipforced serving live (udpm or memq), started and stopped the way systemd does it: READY=1
// awaited through a stand-in notify socket (dir/notify.sock), which is then read all along, as
// systemd reads it; SIGTERM to stop. Its stderr goes to dir/stderr.txt. `prefix` runs it through
// another program (nsenter into another namespace).
struct LiveProcess {
  Child child;
  std::unique_ptr<NotifyListener> notify;
  std::vector<std::string> notifications;  // complete once stop() has returned
  fs::path stderr_path;

  // False if READY=1 did not come within 60 s.
  bool start(const std::string& tipforced, const fs::path& dir, const fs::path& config, const std::string& input_url,
             const std::string& output_url, const std::map<std::string, std::string>& extra_env = {},
             const std::vector<std::string>& extra_args = {}, const std::vector<std::string>& prefix = {});
  // SIGTERM; the exit code (nullopt: killed after 10 s) and how long it took.
  std::pair<std::optional<int>, double> stop();
  ~LiveProcess();

 private:
  void stop_reading();
  std::thread reader_;
  std::atomic<bool> reading_{false};
  std::mutex mutex_;  // notifications, while reader_ runs
};

std::string read_text(const fs::path& path);
void write_text(const fs::path& path, const std::string& text);
// Polls until `pred` holds or `timeout` passes.
template <typename Pred>
bool wait_until(Pred pred, std::chrono::milliseconds timeout) {
  const auto end = std::chrono::steady_clock::now() + timeout;
  while (std::chrono::steady_clock::now() < end) {
    if (pred()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  return pred();
}

}  // namespace tfdtest
