// tfd_tool: inputs and summaries for tipforced's tests and tools/bench_daemon.sh.
//   tfd_tool scan --config C --windows N --samples S --out LOG [--truth CSV] [--spacing-s S]
//   tfd_tool pace --url URL --in LOG --rate R [--count N] [--garbage-every K]
//                                                            publish windows at a steady rate
//   tfd_tool summarize --in OUT.lcmlog [--stalls FILE... --over-us U] estimates, latencies, last stats
//   tfd_tool stalls --duration-s S --out FILE [--period-us P]   the machine's own scheduling stalls
#include <algorithm>
#include <chrono>
#include <map>
#include <cstdio>
#include <fstream>
#include <thread>

#include <time.h>

#include <CLI/CLI.hpp>
#include <lcm/lcm-cpp.hpp>

#include "tipforce/latency_stats_t.hpp"
#include "tipforce/percentile.hpp"
#include "testlib.hpp"

using namespace tfdtest;

namespace {

struct Interval {
  std::int64_t from_utime, to_utime;
};

struct SlowWindow {
  Interval span;  // receive..publish
  long seq;
  int pixel_x, forward_solves;
  std::string message;
};

std::int64_t monotonic_ns() {
  timespec t{};
  clock_gettime(CLOCK_MONOTONIC, &t);
  return static_cast<std::int64_t>(t.tv_sec) * 1'000'000'000 + t.tv_nsec;
}

std::int64_t realtime_utime() {
  return std::chrono::duration_cast<std::chrono::microseconds>(std::chrono::system_clock::now().time_since_epoch())
      .count();
}

// The machine's scheduling latency while tipforced runs beside it: a thread that sleeps to an
// absolute time every period and logs each wake-up later than log_over_us ("<wake utime> <late
// us>", the same wall clock as the estimates' publish_utime). Run under a real-time policy
// (chrt -f), no ordinary task delays it, so what it sees is the machine's own stalls (the
// hypervisor, the kernel's non-preemptible sections): a window's latency that includes one is not
// the inversion's.
int run_stall_probe(double duration_s, long period_us, long log_over_us, const std::string& out_path) {
  if (!(duration_s > 0) || period_us <= 0) {
    std::fprintf(stderr, "tfd_tool stalls: --duration-s and --period-us must be positive\n");
    return 2;
  }
  std::ofstream out(out_path);
  if (!out) {
    std::fprintf(stderr, "tfd_tool stalls: cannot write %s\n", out_path.c_str());
    return 1;
  }
  const std::int64_t period_ns = period_us * 1000, start = monotonic_ns();
  const auto end = start + static_cast<std::int64_t>(duration_s * 1e9);
  std::int64_t due = start + period_ns, max_late_ns = 0;
  long wakeups = 0, over_500us = 0, over_1ms = 0, over_2ms = 0;
  std::vector<std::pair<std::int64_t, std::int64_t>> logged;
  while (due < end) {
    const timespec t{static_cast<time_t>(due / 1'000'000'000), static_cast<long>(due % 1'000'000'000)};
    while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &t, nullptr) != 0) {
    }
    const std::int64_t now = monotonic_ns(), late = now - due;
    ++wakeups;
    max_late_ns = std::max(max_late_ns, late);
    over_500us += late > 500'000;
    over_1ms += late > 1'000'000;
    over_2ms += late > 2'000'000;
    if (late > log_over_us * 1000) logged.emplace_back(realtime_utime(), late / 1000);
    // After a stall, the next wake-up is a period from now, not a burst of missed ones.
    due = std::max(due + period_ns, now + period_ns);
  }
  for (const auto& [utime, late_us] : logged) out << utime << ' ' << late_us << '\n';
  std::printf("stall probe: %ld wake-ups every %ld us over %.1f s; latest %.2f ms; late by > 0.5 ms %ld, > 1 ms %ld, > 2 ms %ld\n",
              wakeups, period_us, duration_s, max_late_ns * 1e-6, over_500us, over_1ms, over_2ms);
  return 0;
}

// How many of the slow windows had a stall of the machine inside their receive..publish time,
// and how long the longest such stall was.
void report_slow_windows_against_stalls(const std::vector<SlowWindow>& slow, double over_us,
                                        const std::vector<std::string>& paths) {
  std::vector<Interval> stall;
  for (const std::string& path : paths) {
    std::ifstream in(path);
    if (!in) {
      std::printf("stalls: cannot read %s\n", path.c_str());
      return;
    }
    std::int64_t wake = 0, late_us = 0;
    // A stall explains a slow window only where it is long against the budget's margin; the probe
    // logs shorter ones too (the hypervisor's usual jitter).
    while (in >> wake >> late_us)
      if (late_us >= 500) stall.push_back({wake - late_us, wake});
  }
  long overlapped = 0;
  std::int64_t longest_inside_us = 0;
  std::vector<const SlowWindow*> unexplained;
  for (const SlowWindow& w : slow) {
    std::int64_t longest = 0;
    for (const Interval& s : stall)
      if (s.from_utime < w.span.to_utime && s.to_utime > w.span.from_utime)
        longest = std::max(longest, s.to_utime - s.from_utime);
    if (longest > 0) ++overlapped;
    else unexplained.push_back(&w);
    longest_inside_us = std::max(longest_inside_us, longest);
  }
  std::printf("slow windows (latency > %.0f us): %zu, %ld of them with a stall of the machine of >= 0.5 ms inside (the longest %.2f ms)\n",
              over_us, slow.size(), overlapped, longest_inside_us * 1e-3);
  // The others are the inversion's own: where did their time go (the message names the stage
  // at which the deadline stopped the fit, or the false continuation)?
  for (std::size_t i = 0; i < unexplained.size() && i < 12; ++i) {
    const SlowWindow& w = *unexplained[i];
    std::printf("  without a stall: seq %ld pixel_x %d, %.2f ms, %d solves: %.150s\n", w.seq, w.pixel_x,
                (w.span.to_utime - w.span.from_utime) * 1e-3, w.forward_solves, w.message.c_str());
  }
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"tfd_tool"};
  app.require_subcommand(1);

  auto* scan = app.add_subcommand("scan", "write a synthetic scan log");
  std::string config_path, out, truth_csv;
  ScanOptions so;
  scan->add_option("--config", config_path)->required();
  scan->add_option("--probe", so.probe);
  scan->add_option("--windows", so.windows);
  scan->add_option("--samples", so.samples);
  scan->add_option("--spacing-s", so.spacing_s);
  scan->add_option("--noise-m", so.noise_m);
  scan->add_option("--width", so.width, "pixels per scan line");
  scan->add_flag("--line-starts-unknown", so.line_starts_unknown, "each line's first window INITIAL_UNKNOWN");
  scan->add_option("--false-continuation-every", so.false_continuation_every,
                   "every N windows one marked CONTINUED whose trajectory starts afresh (0: none)");
  scan->add_option("--pattern", so.pattern, "smooth (default) or domains (issue 9's 1 MHz line)")
      ->transform(CLI::CheckedTransformer(std::map<std::string, ScanOptions::Pattern>{
          {"smooth", ScanOptions::Pattern::smooth}, {"domains", ScanOptions::Pattern::domains}}));
  scan->add_option("--out", out)->required();
  scan->add_option("--truth", truth_csv);

  auto* pace = app.add_subcommand("pace", "publish the windows of a log at a steady rate");
  std::string url, in;
  double rate = 100;
  long count = 0;
  long garbage_every = 0;
  pace->add_option("--url", url)->required();
  pace->add_option("--in", in)->required();
  pace->add_option("--rate", rate)->required();
  pace->add_option("--count", count, "windows to send (the first N; cycles through the log past its end; 0 = all once)");
  pace->add_option("--garbage-every", garbage_every,
                   "after every K-th window also send 16 bytes that are no window (counted as garbage; 0 = never)");

  auto* sum = app.add_subcommand("summarize", "summarise an output log");
  sum->add_option("--in", in)->required();
  bool print = false;
  sum->add_flag("--print", print, "one line per estimate: seq status params");
  std::vector<std::string> stalls_in;
  double over_us = 0;
  sum->add_option("--stalls", stalls_in, "`stalls` logs (one per CPU): which slow windows overlapped a stall of the machine");
  sum->add_option("--over-us", over_us, "latency above which a window counts as slow (with --stalls)");

  auto* stalls = app.add_subcommand(
      "stalls", "wake every --period-us and log each wake-up late by more than --log-over-us (run it under chrt -f)");
  double stall_duration_s = 10;
  long stall_period_us = 200, stall_log_over_us = 200;
  std::string stalls_out;
  stalls->add_option("--duration-s", stall_duration_s)->required();
  stalls->add_option("--period-us", stall_period_us);
  stalls->add_option("--log-over-us", stall_log_over_us);
  stalls->add_option("--out", stalls_out)->required();

  CLI11_PARSE(app, argc, argv);

  if (scan->parsed()) {
    const tipforce::Config config = tipforce::load_config(config_path);
    std::vector<TruthRow> truth;
    auto events = make_scan(config, so, truth_csv.empty() ? nullptr : &truth);
    write_log(out, events);
    if (!truth_csv.empty()) write_truth_csv(truth_csv, truth);
    std::printf("wrote %zu windows to %s\n", events.size(), out.c_str());
    return 0;
  }
  if (pace->parsed()) {
    auto events = read_log(in);
    if (events.empty()) {
      std::fprintf(stderr, "no events in %s\n", in.c_str());
      return 1;
    }
    lcm::LCM lcm(url);
    if (!lcm.good()) return 1;
    const long n = count > 0 ? count : static_cast<long>(events.size());
    long garbage = 0;
    const auto period = std::chrono::duration<double>(1.0 / rate);
    const auto t0 = std::chrono::steady_clock::now();
    for (long i = 0; i < n; ++i) {
      const auto due = t0 + std::chrono::duration_cast<std::chrono::steady_clock::duration>(period * i);
      std::this_thread::sleep_until(due);
      const Event& e = events[static_cast<std::size_t>(i) % events.size()];
      // Cycling through the log: renumber so that each window continues the previous one.
      std::vector<std::uint8_t> data = e.data;
      if (static_cast<std::size_t>(i) >= events.size()) {
        if (auto w = decode<tipforce::deflection_window_t>(e)) {
          w->seq = i;
          w->initial_state = tipforce::deflection_window_t::INITIAL_UNKNOWN;
          data = encode(*w);
        }
      }
      lcm.publish(e.channel, data.data(), static_cast<unsigned>(data.size()));
      if (garbage_every > 0 && (i + 1) % garbage_every == 0) {
        const std::uint8_t junk[16] = {0xde, 0xad, 0xbe, 0xef, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12};
        lcm.publish(e.channel, junk, sizeof(junk));
        ++garbage;
      }
    }
    const double took = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::printf("sent %ld windows (and %ld garbage messages) in %.3f s (%.1f windows/s)\n", n, garbage, took, n / took);
    return 0;
  }
  if (stalls->parsed()) return run_stall_probe(stall_duration_s, stall_period_us, stall_log_over_us, stalls_out);
  if (sum->parsed()) {
    auto events = read_log(in);
    long ok = 0, not_conv = 0, rejected = 0;
    std::vector<double> lat;
    std::int64_t first_receive = 0, last_publish = 0;
    std::optional<tipforce::latency_stats_t> last;
    long n_stats = 0;
    std::vector<SlowWindow> slow;  // the windows above --over-us
    for (const auto& e : events) {
      if (auto est = e.channel == "TIPFORCE_ESTIMATE" ? decode<tipforce::force_estimate_t>(e) : std::nullopt) {
        if (est->status == 0) ++ok;
        else if (est->status == 1) ++not_conv;
        else ++rejected;
        lat.push_back(static_cast<double>(est->publish_utime - est->receive_utime));
        if (lat.back() > over_us)
          slow.push_back({{est->receive_utime, est->publish_utime}, static_cast<long>(est->seq), est->pixel_x,
                          est->forward_solves, est->message});
        if (first_receive == 0 || est->receive_utime < first_receive) first_receive = est->receive_utime;
        last_publish = std::max(last_publish, est->publish_utime);
        if (print) {
          std::printf("%ld %d", static_cast<long>(est->seq), est->status);
          for (int i = 0; i < est->n_params; ++i)
            std::printf(" %s=%.17g+-%.17g", est->param_names[i].c_str(), est->params[i], est->param_sigma[i]);
          std::printf(" misfit=%.3g solves=%d y=%d\n", est->misfit, est->forward_solves, est->pixel_y);
        }
      } else if (auto st = e.channel == "TIPFORCE_STATS" ? decode<tipforce::latency_stats_t>(e) : std::nullopt) {
        last = st;
        ++n_stats;
      }
    }
    double mx = lat.empty() ? 0 : *std::max_element(lat.begin(), lat.end());
    std::printf("estimates %zu ok %ld not_converged %ld rejected %ld latency_us p50 %.0f p99 %.0f max %.0f\n",
                lat.size(), ok, not_conv, rejected, tipforce::percentile(lat, 0.5),
                tipforce::percentile(lat, 0.99), mx);
    if (!lat.empty() && last_publish > first_receive) {
      // From the first window received to the last estimate published, whoever published it.
      const double span_s = static_cast<double>(last_publish - first_receive) * 1e-6;
      std::printf("throughput %.1f windows/s (%zu estimates in %.2f s, first receive to last publish)\n",
                  static_cast<double>(lat.size()) / span_s, lat.size(), span_s);
    }
    if (last)
      std::printf("stats %ld messages; last: received %ld done %ld dropped %ld rejected %ld backend \"%s\" "
                  "foreign_estimates %ld shard %d/%d other_shards %ld\n",
                  n_stats, static_cast<long>(last->windows_received), static_cast<long>(last->windows_done),
                  static_cast<long>(last->windows_dropped), static_cast<long>(last->windows_rejected),
                  last->backend.c_str(), static_cast<long>(last->foreign_estimates), last->shard_index,
                  last->shard_count, static_cast<long>(last->windows_other_shards));
    if (!stalls_in.empty()) report_slow_windows_against_stalls(slow, over_us, stalls_in);
    return 0;
  }
  return 0;
}
