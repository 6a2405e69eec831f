#include "daemon.hpp"

#include <algorithm>
#include <cmath>
#include <csignal>
#include <cstring>
#include <utility>

#include <pthread.h>
#include <unistd.h>

#include <boost/asio/post.hpp>
#include <fmt/format.h>
#include <fmt/ranges.h>
#include <spdlog/spdlog.h>

#include "sd_notify.hpp"
#include "tipforce/deflection_window_t.hpp"
#include "tipforce/force_estimate_t.hpp"
#include "tipforce/latency_stats_t.hpp"
#include "tipforce/setpoint_command_t.hpp"
#include "tipforce/lcm_convert.hpp"
#include "tipforce/shard.hpp"

namespace asio = boost::asio;

namespace tipforce::daemon {
namespace {

// How many LCM messages the IO thread handles per wake-up before it lets timers and results run.
constexpr int kMaxMessagesPerWake = 256;

std::string describe_url(const std::string& url) { return url.empty() ? "(LCM default)" : url; }

// The LCM subscription queue sits in front of ours; it only has to hold what arrives while the IO
// thread is busy with something else for a moment, so it is sized generously: windows must vanish
// only in our queue, where they are counted.
int lcm_queue_capacity(int queue_capacity) { return std::max(1024, 8 * queue_capacity); }

bool fingerprint_matches(const void* data, std::size_t size) {
  if (size < 8) return false;
  int64_t hash = 0;
  return __int64_t_decode_array(data, 0, 8, &hash, 1) == 8 && hash == deflection_window_t::getHash();
}

}  // namespace

bool is_file_url(const std::string& url) { return lcmio::is_file_url(url); }

std::optional<FileInput> check_urls(const std::string& source, const std::string& input_url,
                                    const std::string& output_url_setting) {
  const std::string output_url = output_url_setting.empty() ? input_url : output_url_setting;
  auto refuse = [&](const char* key, const std::string& problem) {
    return StartupError(fmt::format("{}: daemon.{}: {}", source, key, problem));
  };
  auto parse = [&](const char* key, const std::string& url) {
    try {
      return lcmio::parse_file_url(url);
    } catch (const lcmio::LogError& e) {
      throw refuse(key, e.what());
    }
  };
  std::optional<FileInput> in;
  if (is_file_url(input_url)) {
    if (output_url == input_url)
      throw refuse("output_url",
                   fmt::format("input_url is a log file ({}); set output_url to where estimates should go, "
                               "e.g. \"file:///path/estimates.lcmlog?mode=w\"",
                               input_url));
    const lcmio::FileUrl url = parse("input_url", input_url);
    FileInput fi;
    fi.path = url.path;
    for (const auto& [key, value] : url.options) {
      if (key == "speed") {
        char* end = nullptr;
        fi.speed = std::strtod(value.c_str(), &end);
        if (value.empty() || *end != '\0' || !std::isfinite(fi.speed) || fi.speed < 0)
          throw refuse("input_url", fmt::format("speed must be a number >= 0 (0: as fast as possible), got \"{}\"",
                                                value));
      } else if (key == "mode") {
        // LCM's file provider opens mode=w for writing, which truncates the log it was asked to read.
        if (value != "r")
          throw refuse("input_url", fmt::format("mode={}: the input log is only read, and mode=w or mode=a would "
                                                "truncate or change it; drop the option (or use mode=r)",
                                                value));
      } else if (key == "start_timestamp") {
        char* end = nullptr;
        fi.start_timestamp = std::strtoll(value.c_str(), &end, 10);
        if (value.empty() || *end != '\0')
          throw refuse("input_url", fmt::format("start_timestamp must be an integer (µs), got \"{}\"", value));
      } else {
        throw refuse("input_url", fmt::format("unknown option \"{}\" (a file input takes speed, mode=r and "
                                              "start_timestamp)",
                                              key));
      }
    }
    in = fi;
  }
  if (is_file_url(output_url)) {
    const lcmio::FileUrl url = parse("output_url", output_url);
    for (const auto& [key, value] : url.options) {
      if (key != "mode")
        throw refuse("output_url", fmt::format("unknown option \"{}\" (a file output takes mode=w or mode=a)", key));
    }
    const auto mode = url.options.find("mode");
    if (mode == url.options.end() || (mode->second != "w" && mode->second != "a"))
      throw refuse("output_url",
                   fmt::format("a log file output needs mode=w (truncate) or mode=a (append), e.g. \"{}?mode=w\"",
                               output_url.substr(0, output_url.find('?'))));
    // Compared as files, not as strings: another query string, a relative path, a symbolic or a
    // hard link to the input would otherwise get past, and mode=w truncates the input.
    if (in && lcmio::same_file(in->path, url.path))
      throw refuse("output_url", fmt::format("{} is the input log {} (the same file); writing estimates there would "
                                             "destroy the windows being read",
                                             url.path, in->path));
  }
  return in;
}

Daemon::Daemon(const Config& config, ForwardBackend& backend, DaemonOptions options)
    : config_(config),
      backend_(backend),
      options_(std::move(options)),
      backend_description_(backend.description()),
      results_(asio::make_strand(io_)),
      signals_(io_),
      stats_timer_(io_),
      watchdog_timer_(io_),
      stop_timer_(io_),
      input_timer_(io_),
      processor_(config_, backend_),
      queue_(static_cast<std::size_t>(std::max(1, config.daemon.queue_capacity))) {
  const DaemonSettings& d = config_.daemon;
  // Every check first; the input next; the output, which may truncate a file, last.
  file_in_ = check_urls(config_.source, d.input_url, d.output_url);
  file_input_ = file_in_.has_value();
  const std::string output_url = d.output_url.empty() ? d.input_url : d.output_url;
  if (file_input_) {
    try {
      log_in_ = std::make_unique<lcmio::LogReader>(file_in_->path);
    } catch (const lcmio::LogError& e) {
      throw StartupError(fmt::format("cannot read the input log (daemon.input_url): {}", e.what()));
    }
  } else {
    lcm_in_ = std::make_unique<lcm::LCM>(d.input_url);
    if (!lcm_in_->good())
      throw StartupError(fmt::format("cannot open LCM input \"{}\" (daemon.input_url)", describe_url(d.input_url)));
  }
  if (is_file_url(output_url)) {
    const lcmio::FileUrl url = lcmio::parse_file_url(output_url);
    try {
      // The writer checks once more, on the opened file, that it is not the input.
      log_out_ = std::make_unique<lcmio::LogWriter>(url.path, url.options.at("mode") == "a",
                                                    log_in_ ? &log_in_->identity() : nullptr);
    } catch (const lcmio::LogError& e) {
      throw StartupError(fmt::format("cannot write the output log (daemon.output_url): {}", e.what()));
    }
  } else if (lcm_in_ && output_url == d.input_url) {
    lcm_out_ = lcm_in_.get();
  } else {
    lcm_out_owned_ = std::make_unique<lcm::LCM>(output_url);
    if (!lcm_out_owned_->good())
      throw StartupError(fmt::format("cannot open LCM output \"{}\" (daemon.output_url)", describe_url(output_url)));
    lcm_out_ = lcm_out_owned_.get();
  }
}

Daemon::~Daemon() {
  // The descriptors belong to LCM: give them back before LCM closes them.
  for (auto* fd : {&input_fd_, &output_fd_}) {
    if (!*fd) continue;
    boost::system::error_code ec;
    (*fd)->cancel(ec);
    (*fd)->release();
  }
  if (solver_.joinable()) {
    queue_.close();
    solver_.join();
  }
  if (subscription_ != nullptr && lcm_in_) lcm_in_->unsubscribe(subscription_);
  if (estimate_subscription_ != nullptr && estimate_lcm_ != nullptr) estimate_lcm_->unsubscribe(estimate_subscription_);
  if (log_out_) log_out_->close();
}

void set_stop_signals_blocked(bool blocked) {
  sigset_t set;
  sigemptyset(&set);
  sigaddset(&set, SIGTERM);
  sigaddset(&set, SIGINT);
  sigaddset(&set, SIGHUP);
  pthread_sigmask(blocked ? SIG_BLOCK : SIG_UNBLOCK, &set, nullptr);
}

int Daemon::run() {
  const DaemonSettings& d = config_.daemon;
  if (lcm_in_) {
    subscription_ = lcm_in_->subscribe(d.window_channel, &Daemon::on_window, this);
    if (subscription_ == nullptr) {
      spdlog::error("cannot subscribe to {} on {}", d.window_channel, describe_url(d.input_url));
      return 1;
    }
    subscription_->setQueueCapacity(lcm_queue_capacity(d.queue_capacity));
    input_fd_.emplace(io_, lcm_in_->getFileno());
  }
  subscribe_estimates();

  std::vector<std::string> probes, advised;
  for (const auto& [name, probe] : config_.probes) {
    const auto& periods = probe.options.prepare_sample_periods_s;
    probes.push_back(periods.empty() ? name : fmt::format("{} (prepared for {} s)", name, fmt::join(periods, ", ")));
    if (probe.advisor) advised.push_back(name);
  }
  const std::string advisor_note =
      advised.empty() ? std::string()
                      : fmt::format(", setpoint advisor for [{}] on {}", fmt::join(advised, ", "), d.setpoint_channel);
  spdlog::info(
      "tipforced {} started: backend \"{}\" ({}), config {}, probes [{}], input {} channel {}, output {} channels "
      "{} + {}{}, queue {}{}, stats every {} s, shard {}",
      options_.version, backend_description_, options_.backend_note, options_.config_path,
      fmt::join(probes, ", "), describe_url(d.input_url), d.window_channel,
      describe_url(d.output_url.empty() ? d.input_url : d.output_url), d.estimate_channel, d.stats_channel,
      advisor_note, queue_.capacity(), file_input_ ? " (file input: back-pressure, no drops)" : "", d.stats_period_s,
      d.shard.sharded() ? d.shard.describe() : std::string("0/1 (every window)"));

  signals_.add(SIGINT);
  signals_.add(SIGTERM);
  signals_.add(SIGHUP);
  // Created while the stop signals are still blocked, the solver thread never receives them.
  solver_ = std::thread([this] { solver_main(); });
  period_start_ = std::chrono::steady_clock::now();
  arm_signals();
  // A signal that arrived during start-up is delivered now, to the signal_set: a normal stop.
  set_stop_signals_blocked(false);
  arm_stats_timer();
  sd_notify(fmt::format("READY=1\nSTATUS=serving {} on {}\nMAINPID={}", d.window_channel, describe_url(d.input_url),
                        ::getpid()));
  if (auto interval = sd_watchdog_interval()) arm_watchdog(*interval / 2);
  // Anything already waiting (a log file is readable at once) is taken before the first wait.
  asio::post(io_, [this] { drain_input(); });
  if (output_fd_) asio::post(io_, [this] { drain_output_watch(); });

  io_.run();
  // The signal_set is about to go, and with it the handlers: blocked again, a late SIGTERM cannot
  // kill the process on its way out.
  set_stop_signals_blocked(true);

  if (abandon_solver_) {
    // The window in progress did not finish in time; the solver thread cannot be interrupted.
    // Close the output (flushes a log file) and let the caller leave without joining.
    if (input_fd_) input_fd_->release();
    input_fd_.reset();
    if (output_fd_) output_fd_->release();
    output_fd_.reset();
    lcm_out_owned_.reset();
    return exit_code_;
  }
  if (solver_.joinable()) solver_.join();
  return exit_code_;
}

// ---- input (IO thread) ---------------------------------------------------------------------------

void Daemon::on_window(const lcm::ReceiveBuffer* rbuf, const std::string& /*channel*/) {
  const std::int64_t now = lcmio::now_utime();
  // LCM's receive time includes the time spent in LCM's own queue.
  std::int64_t received = now;
  if (rbuf->recv_utime <= now && now - rbuf->recv_utime < 10'000'000) received = rbuf->recv_utime;
  accept_message(rbuf->data, static_cast<std::size_t>(rbuf->data_size), received);
}

void Daemon::accept_message(const void* data, std::size_t size, std::int64_t received) {
  stats_.on_received();
  const ShardSpec& shard = config_.daemon.shard;
  if (shard.sharded() && lcmio::window_shard(data, size, shard) != shard.index) {
    // Another shard answers it (LCM gives every subscriber every window): ignored, and counted
    // apart from drops, which are windows this daemon owed an answer.
    stats_.on_other_shard();
    return;
  }
  if (!fingerprint_matches(data, size)) {
    // Not a window at all: nothing to answer. A cheap check, so that garbage never takes a
    // queue slot away from real windows; the solver's decode checks everything else.
    stats_.on_unattributable();
    warn_input(fmt::format("ignored a message on {} that is not a tipforce.deflection_window_t ({} bytes{})",
                           config_.daemon.window_channel, size, size < 8 ? "" : ", fingerprint mismatch"));
    return;
  }
  Job job;
  const auto* bytes = static_cast<const std::uint8_t*>(data);
  job.bytes.assign(bytes, bytes + size);
  job.receive_utime = received;
  if (file_input_ && queue_.try_push(job)) return;  // drain_input() keeps room: never drops
  if (auto dropped = queue_.push(std::move(job))) {
    stats_.on_dropped();
    if (drop_warnings_.allow()) {
      const auto held = drop_warnings_.take_suppressed();
      spdlog::warn("queue full ({} windows): dropped the oldest waiting window ({} dropped so far{})",
                   queue_.capacity(), stats_.totals().dropped,
                   held > 0 ? fmt::format(", {} similar lines suppressed", held) : std::string());
    }
  }
}

void Daemon::arm_input() {
  if (input_ != Input::reading || !input_fd_) return;
  input_fd_->async_wait(asio::posix::stream_descriptor::wait_read, [this](const boost::system::error_code& ec) {
    if (ec) return;  // cancelled: stopping
    drain_input();
  });
}

void Daemon::drain_input() {
  if (input_ == Input::paused) input_ = Input::reading;
  if (input_ != Input::reading) return;
  if (log_in_) {
    if (drain_file_input()) asio::post(io_, [this] { drain_input(); });
    return;
  }
  for (int i = 0; i < kMaxMessagesPerWake; ++i) {
    const int status = lcm_in_->handleTimeout(0);
    if (status < 0) {
      on_input_end(true);
      return;
    }
    if (status == 0) {
      arm_input();
      return;
    }
    if (stopping_) return;
  }
  asio::post(io_, [this] { drain_input(); });
}

bool Daemon::drain_file_input() {
  for (int i = 0; i < kMaxMessagesPerWake; ++i) {
    if (queue_.full()) {
      // Back-pressure: a recorded log is read no faster than it is solved, so no window of it is
      // dropped. Reading resumes when the solver hands back a result (on_result).
      input_ = Input::paused;
      return false;
    }
    if (!held_event_) {
      held_event_ = log_in_->next();
      for (const lcmio::LogDamage& damage : log_in_->take_damage()) {
        stats_.on_input_damaged();
        if (!damage_warnings_.allow()) continue;
        const auto held = damage_warnings_.take_suppressed();
        spdlog::warn("input log {}: skipped {} damaged bytes at offset {} ({}); reading on from the next intact "
                     "event ({} damaged stretches so far{})",
                     file_in_->path, damage.bytes, damage.offset, damage.why, stats_.totals().input_damaged,
                     held > 0 ? fmt::format(", {} similar lines suppressed", held) : std::string());
      }
      if (!held_event_) {
        if (!log_in_->error().empty()) spdlog::error("{}", log_in_->error());
        on_input_end(!log_in_->error().empty());
        return false;
      }
      // What LCM's subscription did: other channels are not ours.
      if (held_event_->channel != config_.daemon.window_channel ||
          held_event_->timestamp < file_in_->start_timestamp) {
        held_event_.reset();
        continue;
      }
    }
    if (file_in_->speed > 0) {
      // Replay on the log's clock, as LCM's file provider does: each event at its offset from the
      // first, divided by the speed (clamped, so a damaged timestamp cannot stall the replay).
      const auto now = std::chrono::steady_clock::now();
      if (!first_timestamp_) {
        first_timestamp_ = held_event_->timestamp;
        replay_start_ = now;
      }
      const double offset_s = std::clamp(
          (static_cast<double>(held_event_->timestamp) - static_cast<double>(*first_timestamp_)) * 1e-6 /
              file_in_->speed,
          0.0, 3600.0);
      const auto due = replay_start_ + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                           std::chrono::duration<double>(offset_s));
      if (due > now) {
        input_timer_.expires_at(due);
        input_timer_.async_wait([this](const boost::system::error_code& ec) {
          if (!ec) drain_input();
        });
        return false;
      }
    }
    const lcmio::LogEvent event = std::move(*held_event_);
    held_event_.reset();
    // A log's own receive times are synthetic: latency counts from when tipforced read the window.
    accept_message(event.data.data(), event.data.size(), lcmio::now_utime());
    if (stopping_) return false;
  }
  return true;
}

void Daemon::on_input_end(bool error) {
  if (error) {
    spdlog::error("LCM input {} failed; stopping", describe_url(config_.daemon.input_url));
    exit_code_ = 1;
  } else {
    spdlog::info("end of input log after {} windows; finishing the {} queued", stats_.totals().received,
                 queue_.size());
  }
  input_ = Input::ended;
  if (input_fd_) {
    boost::system::error_code ec;
    input_fd_->cancel(ec);
  }
  // Every window read gets its estimate: the solver empties the queue, then exits.
  queue_.close();
}

void Daemon::warn_input(const std::string& what) {
  if (!input_warnings_.allow()) return;
  const auto held = input_warnings_.take_suppressed();
  if (held > 0)
    spdlog::warn("{} ({} similar lines suppressed)", what, held);
  else
    spdlog::warn("{}", what);
}

// ---- another publisher on the estimate channel (IO thread) --------------------------------------

void Daemon::subscribe_estimates() {
  // A log file output has no other writer; there is nothing to watch.
  if (lcm_out_ == nullptr) return;
  const std::string& channel = config_.daemon.estimate_channel;
  estimate_subscription_ = lcm_out_->subscribe(channel, &Daemon::on_estimate, this);
  if (estimate_subscription_ == nullptr) {
    spdlog::warn("cannot subscribe to {}: another publisher answering this daemon's windows would go unnoticed",
                 channel);
    return;
  }
  estimate_lcm_ = lcm_out_;
  estimate_subscription_->setQueueCapacity(lcm_queue_capacity(config_.daemon.queue_capacity));
  // On the input's LCM the input loop handles it; an output LCM of its own is watched here.
  if (estimate_lcm_ != lcm_in_.get()) output_fd_.emplace(io_, estimate_lcm_->getFileno());
}

void Daemon::arm_output_watch() {
  if (!output_fd_ || finished_) return;
  output_fd_->async_wait(asio::posix::stream_descriptor::wait_read, [this](const boost::system::error_code& ec) {
    if (ec) return;  // cancelled: finishing
    drain_output_watch();
  });
}

void Daemon::drain_output_watch() {
  for (int i = 0; i < kMaxMessagesPerWake; ++i) {
    if (finished_) return;
    const int status = estimate_lcm_->handleTimeout(0);
    if (status < 0) {
      // Publishing through it will fail too, and be counted there; only the watch ends here.
      spdlog::warn("LCM output {}: receiving failed; no longer watching {} for another publisher",
                   describe_url(config_.daemon.output_url), config_.daemon.estimate_channel);
      return;
    }
    if (status == 0) {
      arm_output_watch();
      return;
    }
  }
  asio::post(io_, [this] { drain_output_watch(); });
}

void Daemon::on_estimate(const lcm::ReceiveBuffer* rbuf, const std::string& channel) {
  if (finished_) return;
  const std::string_view bytes(static_cast<const char*>(rbuf->data), static_cast<std::size_t>(rbuf->data_size));
  if (own_estimates_.take_echo(fnv1a64(bytes))) return;
  // Only the header is read: the arrays of a message nobody vouches for are not allocated.
  const auto header = lcmio::decode_estimate_header(rbuf->data, bytes.size());
  if (!header) return;  // not an estimate; whatever it is, it answers no window of ours
  if (!config_.daemon.shard.owns(header->probe, header->pixel_y)) return;  // another shard's, as it should be
  stats_.on_foreign_estimate();
  if (!foreign_warnings_.allow()) return;
  const auto held = foreign_warnings_.take_suppressed();
  spdlog::warn("another publisher answered probe '{}' seq {} pixel ({}, {}) on {}, a window this daemon answers "
               "(shard {}): two daemons on one window channel, or one shard index used twice? {} such estimates so "
               "far{}",
               header->probe, header->seq, header->pixel_x, header->pixel_y, channel,
               config_.daemon.shard.describe(), stats_.totals().foreign_estimates,
               held > 0 ? fmt::format(" ({} similar lines suppressed)", held) : std::string());
}

// ---- solver thread -----------------------------------------------------------------------------

void Daemon::solver_main() {
  while (auto job = queue_.pop()) {
    solver_busy_ = true;
    // A live window's budget counts from its receipt (queue wait included); a log file's from
    // now: it is read ahead of the solver by design (back-pressure), and its windows would
    // otherwise spend their budget waiting in the full queue.
    lcmio::ProcessedWindow result =
        processor_.process(job->bytes.data(), job->bytes.size(), job->receive_utime,
                           file_input_ ? std::optional<std::int64_t>(lcmio::now_utime()) : std::nullopt);
    job.reset();
    // The estimate goes out before the advisor's forward solves; its command follows it.
    asio::post(results_, [this, r = std::move(result)]() mutable { on_result(std::move(r)); });
    if (auto command = processor_.advise_last())
      asio::post(results_, [this, c = std::move(*command)]() mutable { on_command(std::move(c)); });
    solver_busy_ = false;
  }
  // The strand keeps this after every result posted above.
  asio::post(results_, [this] { on_solver_exit(); });
}

// ---- results (IO thread) -----------------------------------------------------------------------

void Daemon::on_result(lcmio::ProcessedWindow result) {
  if (finished_) return;
  if (!result.estimate) {
    stats_.on_unattributable();
    warn_input(fmt::format("ignored an undecodable message on {}: {}", config_.daemon.window_channel, result.reason));
  } else {
    force_estimate_t& e = *result.estimate;
    e.publish_utime = lcmio::now_utime();
    publish(config_.daemon.estimate_channel, e, "an estimate");
    stats_.on_done(static_cast<double>(e.publish_utime - e.receive_utime), result.solve_seconds * 1e6,
                   result.rejected);
    if (result.rejected) {
      if (e.status == force_estimate_t::STATUS_REJECTED)
        warn_input(fmt::format("rejected window probe '{}' seq {} pixel ({}, {}): {}", e.probe, e.seq, e.pixel_x,
                               e.pixel_y, result.reason));
    } else if (e.status == force_estimate_t::STATUS_NOT_CONVERGED) {
      spdlog::debug("window probe '{}' seq {}: not converged: {}", e.probe, e.seq, e.message);
    }
  }
  if (input_ == Input::paused) drain_input();
}

void Daemon::on_command(setpoint_command_t command) {
  if (finished_) return;
  command.publish_utime = lcmio::now_utime();
  publish(config_.daemon.setpoint_channel, command, "a setpoint command");
  ++commands_published_;
  if (command.status == setpoint_command_t::STATUS_CORRECTION || command.status == setpoint_command_t::STATUS_OUT_OF_RANGE)
    spdlog::debug("setpoint command probe '{}' seq {}: {}", command.probe, command.seq, command.reason);
}

void Daemon::on_solver_exit() {
  if (finished_) return;
  finish();
}

// ---- stopping ----------------------------------------------------------------------------------

void Daemon::arm_signals() {
  signals_.async_wait([this](const boost::system::error_code& ec, int signo) {
    if (ec) return;
    if (signo == SIGHUP) {
      // Logs go to stderr (the journal under systemd): there is no file to reopen.
      spdlog::info("SIGHUP: logging to stderr, nothing to reopen");
      spdlog::default_logger()->flush();
    } else if (!stopping_) {
      begin_stop(signo == SIGTERM ? "SIGTERM" : "SIGINT");
    } else {
      spdlog::info("{} again: already stopping", signo == SIGTERM ? "SIGTERM" : "SIGINT");
    }
    arm_signals();
  });
}

void Daemon::begin_stop(const char* why) {
  stopping_ = true;
  sd_notify("STOPPING=1");
  // Stop taking windows.
  input_ = Input::stopped;
  if (input_fd_) {
    boost::system::error_code ec;
    input_fd_->cancel(ec);
  }
  // What is still waiting is dropped and counted; the window in progress is finished.
  const auto left = queue_.close_and_take();
  stats_.on_dropped(static_cast<std::int64_t>(left.size()));
  spdlog::info("{}: stopping; {} queued windows dropped, {} in progress", why, left.size(),
               solver_busy_ ? "finishing the one" : "none");
  input_timer_.cancel();
  stop_timer_.expires_after(options_.stop_deadline);
  stop_timer_.async_wait([this](const boost::system::error_code& ec) {
    if (ec || finished_) return;
    spdlog::warn("the window in progress did not finish within {} ms; counted as dropped",
                 options_.stop_deadline.count());
    stats_.on_dropped();
    abandon_solver_ = true;
    finish();
  });
}

// A file input that gave nothing to solve is bad input, exit 2 as for tipforce invert (README,
// "Exit codes"): no window on the channel (empty, not an LCM log, another channel; a log damaged
// from its first event on is damaged input instead, 3), or every window of this daemon's share
// rejected (a config without the windows' probe, say). 0 otherwise (finish() then applies 3).
int Daemon::file_input_verdict(const LatencyStats::Totals& t) const {
  const auto& d = config_.daemon;
  if (t.received == 0) {
    if (t.input_damaged > 0 && lcmio::starts_with_sync_word(file_in_->path)) return 0;
    spdlog::error("{}: no windows on channel {} (empty, not an LCM log, or another channel)", file_in_->path,
                  d.window_channel);
    return 2;
  }
  if (t.done > 0 && t.rejected - t.unattributable == t.done) {
    spdlog::error("{}: every one of the {} windows was rejected (reasons above); no window was solved", file_in_->path,
                  t.done);
    return 2;
  }
  return 0;
}

void Daemon::finish() {
  finished_ = true;
  boost::system::error_code ec;
  stats_timer_.cancel();
  watchdog_timer_.cancel();
  stop_timer_.cancel();
  input_timer_.cancel();
  signals_.cancel(ec);
  if (input_fd_) input_fd_->cancel(ec);
  if (output_fd_) output_fd_->cancel(ec);
  publish_stats(true);
  // Closing a log file syncs it to the disk: the last place a write error can show (one that
  // earlier writes already showed and counted is not counted again).
  if (log_out_ && !log_out_->close() && stats_.totals().output_errors == 0) {
    stats_.on_output_error();
    exit_code_ = 1;
    spdlog::error("output log: {}", log_out_->error());
  }
  if (!stopping_) sd_notify("STOPPING=1");
  const auto& t = stats_.totals();
  if (exit_code_ == 0 && file_input_) exit_code_ = file_input_verdict(t);
  if (exit_code_ == 0 && t.input_damaged > 0) exit_code_ = kExitInputDamaged;
  spdlog::info("tipforced stopped: {} windows received, {} estimates ({} rejected), {} dropped, {} unattributable, "
               "{} damaged input stretches skipped, {} output errors, {} estimates by another publisher, {} windows "
               "of other shards, {} setpoint commands; exit {}",
               t.received, t.done, t.rejected - t.unattributable, t.dropped, t.unattributable, t.input_damaged,
               t.output_errors, t.foreign_estimates, t.other_shards, commands_published_, exit_code_);
  if (const LatencyStats::RunLatency run = stats_.run_latency(); run.count > 0)
    spdlog::info("receive->publish over the run ({} estimates): p50 {:.0f} us, p99 {:.0f} us (to 1 %), max {:.0f} us",
                 run.count, run.p50_us, run.p99_us, run.max_us);
  spdlog::default_logger()->flush();
  io_.stop();
}

// ---- stats and watchdog ------------------------------------------------------------------------

void Daemon::arm_stats_timer() {
  const auto period = std::chrono::duration_cast<std::chrono::steady_clock::duration>(
      std::chrono::duration<double>(config_.daemon.stats_period_s));
  stats_timer_.expires_at(period_start_ + period);
  stats_timer_.async_wait([this](const boost::system::error_code& ec) {
    if (ec || finished_) return;
    publish_stats(false);
    arm_stats_timer();
  });
}

void Daemon::publish_stats(bool final) {
  const auto now = std::chrono::steady_clock::now();
  const double period_s = std::chrono::duration<double>(now - period_start_).count();
  period_start_ = now;
  latency_stats_t m =
      stats_.take_period(lcmio::now_utime(), backend_description_, period_s, static_cast<int>(queue_.size()));
  m.shard_index = config_.daemon.shard.index;
  m.shard_count = config_.daemon.shard.count;
  publish(config_.daemon.stats_channel, m, "stats");
  spdlog::info(
      "{}stats: {:.1f} windows/s, received {}, done {}, dropped {}, rejected {}, queue {}; latency p50 {:.0f} "
      "p90 {:.0f} p99 {:.0f} max {:.0f} us; solve p50 {:.0f} p99 {:.0f} us; input damaged {}, output errors {}, "
      "foreign estimates {}; shard {}/{}, windows of other shards {}",
      final ? "final " : "", m.windows_per_s, m.windows_received, m.windows_done, m.windows_dropped,
      m.windows_rejected, m.queue_depth, m.latency_p50_us, m.latency_p90_us, m.latency_p99_us, m.latency_max_us,
      m.solve_p50_us, m.solve_p99_us, m.input_damaged, m.output_errors, m.foreign_estimates, m.shard_index,
      m.shard_count, m.windows_other_shards);
}

template <typename Msg>
void Daemon::publish(const std::string& channel, const Msg& message, const char* what) {
  bool ok = false;
  std::string why;
  std::vector<std::uint8_t> bytes(static_cast<std::size_t>(message.getEncodedSize()));
  message.encode(bytes.data(), 0, static_cast<int>(bytes.size()));
  if (log_out_) {
    ok = log_out_->write(channel, lcmio::now_utime(), bytes.data(), bytes.size());
    why = log_out_->error();
  } else {
    // Remembered before it goes out: on memq the echo can be delivered before publish returns.
    if (estimate_lcm_ != nullptr && channel == config_.daemon.estimate_channel)
      own_estimates_.published(
          fnv1a64(std::string_view(reinterpret_cast<const char*>(bytes.data()), bytes.size())));
    ok = lcm_out_->publish(channel, bytes.data(), static_cast<unsigned>(bytes.size())) == 0;
    why = "LCM publish failed";
  }
  if (ok) return;
  // Lost output is lost data: counted, logged, and the exit code says so.
  stats_.on_output_error();
  exit_code_ = 1;
  if (publish_errors_.allow()) {
    const auto held = publish_errors_.take_suppressed();
    spdlog::error("could not publish {} on {}: {} ({} output errors so far{})", what, channel, why,
                  stats_.totals().output_errors,
                  held > 0 ? fmt::format(", {} similar lines suppressed", held) : std::string());
  }
}

void Daemon::arm_watchdog(std::chrono::microseconds interval) {
  sd_notify("WATCHDOG=1");
  watchdog_timer_.expires_after(interval);
  watchdog_timer_.async_wait([this, interval](const boost::system::error_code& ec) {
    if (ec || finished_) return;
    arm_watchdog(interval);
  });
}

}  // namespace tipforce::daemon
