#pragma once
// tipforced's service: LCM in, a bounded queue, one solver thread, LCM out, stats, systemd.
//
// Threads: the IO thread runs the Boost.Asio io_context and is the only one that touches LCM (it
// receives windows, publishes estimates and stats, answers signals and pings the watchdog); it
// never computes. The solver thread pops windows from the queue, answers them through
// WindowProcessor (the code path of `tipforce invert`) and hands each estimate back to the IO
// thread with asio::post. See daemon/README-daemon.md.
#include <atomic>
#include <chrono>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include <boost/asio/io_context.hpp>
#include <boost/asio/posix/stream_descriptor.hpp>
#include <boost/asio/signal_set.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/asio/strand.hpp>
#include <lcm/lcm-cpp.hpp>

#include "bounded_queue.hpp"
#include "latency_stats.hpp"
#include "rate_limiter.hpp"
#include "tipforce/config.hpp"
#include "tipforce/forward.hpp"
#include "tipforce/window_processor.hpp"

namespace tipforce::daemon {

struct DaemonOptions {
  std::string config_path;     // for the start-up line
  std::string version;         // for the start-up line
  std::string backend_note;    // make_backend's note, for the start-up line
  // How long after SIGTERM/SIGINT the window in progress may still take before tipforced gives
  // up on it (counts it as dropped) and exits anyway.
  std::chrono::milliseconds stop_deadline{1500};
};

// Thrown before anything is subscribed when the URLs cannot be used.
class StartupError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

bool is_file_url(const std::string& url);

class Daemon {
 public:
  // Creates the LCM instances and the per-probe inverters; subscribes nothing yet. Throws
  // StartupError (bad URL, unusable file) or ConfigError (a probe's model cannot be built).
  Daemon(const Config& config, ForwardBackend& backend, DaemonOptions options);
  ~Daemon();

  Daemon(const Daemon&) = delete;
  Daemon& operator=(const Daemon&) = delete;

  // Subscribes, reports READY to systemd and serves until SIGTERM/SIGINT or, for file input, the
  // end of the log. Returns the process exit code (0 on a clean stop).
  int run();

  // Exit through std::_Exit after run() because the solver thread could not be joined in time.
  bool must_abandon_solver() const { return abandon_solver_; }

 private:
  struct Job {
    std::vector<std::uint8_t> bytes;
    std::int64_t receive_utime = 0;
  };
  enum class Input { reading, paused, ended, stopped };

  void on_window(const lcm::ReceiveBuffer* rbuf, const std::string& channel);
  void arm_input();
  void drain_input();
  void on_input_end(bool error);
  void solver_main();
  void on_result(lcmio::ProcessedWindow result);
  void on_solver_exit();
  void begin_stop(const char* why);
  void arm_signals();
  void arm_stats_timer();
  void arm_watchdog(std::chrono::microseconds interval);
  void publish_stats(bool final);
  void finish();
  void warn_input(const std::string& what);

  Config config_;
  ForwardBackend& backend_;
  DaemonOptions options_;
  std::string backend_description_;
  bool file_input_ = false;

  boost::asio::io_context io_;
  boost::asio::strand<boost::asio::io_context::executor_type> results_;
  std::unique_ptr<lcm::LCM> lcm_in_;
  std::unique_ptr<lcm::LCM> lcm_out_owned_;  // only when output_url differs from input_url
  lcm::LCM* lcm_out_ = nullptr;
  lcm::Subscription* subscription_ = nullptr;
  std::optional<boost::asio::posix::stream_descriptor> input_fd_;
  boost::asio::signal_set signals_;
  boost::asio::steady_timer stats_timer_;
  boost::asio::steady_timer watchdog_timer_;
  boost::asio::steady_timer stop_timer_;

  lcmio::WindowProcessor processor_;  // solver thread only
  BoundedQueue<Job> queue_;
  std::thread solver_;
  std::atomic<bool> solver_busy_{false};

  LatencyStats stats_;
  std::chrono::steady_clock::time_point period_start_;
  Input input_ = Input::reading;
  bool stopping_ = false;
  bool finished_ = false;
  bool abandon_solver_ = false;
  int exit_code_ = 0;
  RateLimiter input_warnings_{10, std::chrono::seconds(10)};
  RateLimiter drop_warnings_{5, std::chrono::seconds(10)};
  RateLimiter publish_errors_{5, std::chrono::seconds(10)};
};

}  // namespace tipforce::daemon
