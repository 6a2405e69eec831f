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
#include "own_estimates.hpp"
#include "rate_limiter.hpp"
#include "tipforce/config.hpp"
#include "tipforce/event_log.hpp"
#include "tipforce/forward.hpp"
#include "tipforce/setpoint_command_t.hpp"
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

// Thrown before anything is subscribed, and before any output is opened, when the URLs cannot be
// used.
class StartupError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

bool is_file_url(const std::string& url);

// SIGTERM, SIGINT and SIGHUP are blocked from the first line of main() (one that arrives during
// start-up then waits instead of killing the process, as SIGHUP's default action would) until
// Daemon::run's signal_set has them; run() unblocks them, and blocks them again on its way out.
void set_stop_signals_blocked(bool blocked);

// Exit codes of run(): besides 0 (clean stop, nothing lost) and 1 (the input failed, or an
// estimate or stats message could not be written), this one: every readable window of an input
// log was answered, but damaged stretches of the log were skipped (counted in input_damaged).
constexpr int kExitInputDamaged = 3;

// How a file:// input is replayed (the options of LCM's own file provider that tipforced honours).
struct FileInput {
  std::string path;
  double speed = 1.0;                // LCM's default: real time; 0 = as fast as the solver goes
  std::int64_t start_timestamp = 0;  // events stamped earlier are skipped
};
// Checks the URLs before anything is opened: a file input only read (no mode=w or a), a file
// output with an explicit mode=w or mode=a, no unknown options, and the output not the input
// file (compared as files: device and inode, or the resolved path). Throws StartupError naming
// `source` and the key.
std::optional<FileInput> check_urls(const std::string& source, const std::string& input_url,
                                    const std::string& output_url);

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
  void on_estimate(const lcm::ReceiveBuffer* rbuf, const std::string& channel);
  void subscribe_estimates();
  void arm_output_watch();
  void drain_output_watch();
  void accept_message(const void* data, std::size_t size, std::int64_t received);
  void arm_input();
  void drain_input();
  bool drain_file_input();  // false when it stopped (paused, waiting, ended)
  int file_input_verdict(const LatencyStats::Totals& t) const;
  void on_input_end(bool error);
  void solver_main();
  void on_result(lcmio::ProcessedWindow result);
  void on_command(setpoint_command_t command);
  void on_solver_exit();
  void begin_stop(const char* why);
  void arm_signals();
  void arm_stats_timer();
  void arm_watchdog(std::chrono::microseconds interval);
  void publish_stats(bool final);
  template <typename Msg>
  void publish(const std::string& channel, const Msg& message, const char* what);
  void finish();
  void warn_input(const std::string& what);

  Config config_;
  ForwardBackend& backend_;
  DaemonOptions options_;
  std::string backend_description_;
  bool file_input_ = false;
  std::optional<FileInput> file_in_;

  boost::asio::io_context io_;
  boost::asio::strand<boost::asio::io_context::executor_type> results_;
  std::unique_ptr<lcm::LCM> lcm_in_;         // network (or memq) input
  std::unique_ptr<lcmio::LogReader> log_in_;  // file input: our reader, which resyncs past damage
  std::unique_ptr<lcm::LCM> lcm_out_owned_;  // only when output_url differs from input_url
  lcm::LCM* lcm_out_ = nullptr;
  std::unique_ptr<lcmio::LogWriter> log_out_;  // file output: our writer, which reports write errors
  // Pacing a file input at speed > 0: the event waiting for its time, and the replay's clock.
  std::optional<lcmio::LogEvent> held_event_;
  std::optional<std::int64_t> first_timestamp_;
  std::chrono::steady_clock::time_point replay_start_;
  lcm::Subscription* subscription_ = nullptr;
  std::optional<boost::asio::posix::stream_descriptor> input_fd_;
  // The estimate channel, watched for another publisher's answers to this daemon's windows. On
  // the output LCM (the input's when they are one); its descriptor is watched here only when the
  // output is an LCM of its own (output_fd_).
  lcm::LCM* estimate_lcm_ = nullptr;
  lcm::Subscription* estimate_subscription_ = nullptr;
  std::optional<boost::asio::posix::stream_descriptor> output_fd_;
  OwnEstimates own_estimates_;
  boost::asio::signal_set signals_;
  boost::asio::steady_timer stats_timer_;
  boost::asio::steady_timer watchdog_timer_;
  boost::asio::steady_timer stop_timer_;
  boost::asio::steady_timer input_timer_;

  lcmio::WindowProcessor processor_;  // solver thread only
  BoundedQueue<Job> queue_;
  std::thread solver_;
  std::atomic<bool> solver_busy_{false};

  LatencyStats stats_;
  std::int64_t commands_published_ = 0;  // setpoint commands (issue 13), for the stop line
  std::chrono::steady_clock::time_point period_start_;
  Input input_ = Input::reading;
  bool stopping_ = false;
  bool finished_ = false;
  bool abandon_solver_ = false;
  int exit_code_ = 0;
  RateLimiter input_warnings_{10, std::chrono::seconds(10)};
  RateLimiter drop_warnings_{5, std::chrono::seconds(10)};
  RateLimiter publish_errors_{5, std::chrono::seconds(10)};
  RateLimiter damage_warnings_{10, std::chrono::seconds(10)};
  // Another publisher answers every window it sees: one line a minute says so, with the count.
  RateLimiter foreign_warnings_{1, std::chrono::seconds(60)};
};

}  // namespace tipforce::daemon
