// `tipforce invert`: every window of a log, in order, through the same WindowProcessor tipforced
// uses, into an estimates log. Reads and writes with lcmio's LogReader/LogWriter (damaged events
// skipped and counted, write errors seen), as tipforced's file mode does.
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <memory>
#include <optional>

#include "cli_common.hpp"
#include "commands.hpp"
#include "tipforce/backend.hpp"
#include "tipforce/event_log.hpp"
#include "tipforce/lcm_convert.hpp"
#include "tipforce/shard.hpp"
#include "tipforce/window_processor.hpp"

namespace tipforce::cli {
namespace {

// --shard I/N with --shard-by (or the config's daemon.shard.by): which windows this run answers.
// Throws CLI::ValidationError naming the option and the problem.
ShardSpec parse_shard(const std::string& text, const std::string& by_option, const Config& config) {
  ShardSpec spec;
  const auto slash = text.find('/');
  std::size_t used_i = 0, used_n = 0;
  try {
    if (slash == std::string::npos) throw std::invalid_argument("no slash");
    spec.index = std::stoi(text.substr(0, slash), &used_i);
    spec.count = std::stoi(text.substr(slash + 1), &used_n);
  } catch (const std::exception&) {
    used_i = used_n = std::string::npos;
  }
  if (slash == std::string::npos || used_i != slash || used_n != text.size() - slash - 1)
    throw CLI::ValidationError("--shard", "expected I/N (shard I of N, counting from 0), got \"" + text + "\"");
  if (const std::string problem = shard_problem(spec); !problem.empty())
    throw CLI::ValidationError("--shard", problem + " (from \"" + text + "\")");
  if (by_option == "probe" || by_option == "line") {
    spec.by = by_option == "line" ? ShardBy::line : ShardBy::probe;
  } else if (config.daemon.shard.sharded()) {
    spec.by = config.daemon.shard.by;
  } else {
    // No default: shards that split by different keys would answer some windows twice, others never.
    throw CLI::ValidationError("--shard", "say how the log is split: --shard-by line (scan lines, pixel_y) or "
                                          "--shard-by probe (whole probes), or daemon.shard.by in the config");
  }
  return spec;
}

}  // namespace

void add_invert_command(CLI::App& app) {
  auto* cmd = app.add_subcommand("invert", "Invert every window of an LCM log into force estimates");
  struct Opts {
    std::string config, in, out, backend, shard, shard_by;
  };
  auto o = std::make_shared<Opts>();
  cmd->add_option("--config", o->config, "Config file (TOML)")->required()->check(CLI::ExistingFile);
  cmd->add_option("--in", o->in, "Input LCM log with windows")->required()->check(CLI::ExistingFile);
  cmd->add_option("--out", o->out, "Output LCM log with estimates")->required();
  // Checked while parsing: a misspelt backend is a usage error (exit 2), as in tipforced.
  cmd->add_option("--backend", o->backend, "auto | cpu | cuda (default: the config's)")
      ->check(CLI::IsMember({"auto", "cpu", "cuda"}));
  cmd->add_option("--shard", o->shard,
                  "I/N: answer only shard I of N (from 0) of the windows, as tipforced with daemon.shard does; "
                  "run the N shards side by side (GNU parallel, a Slurm array) and map their logs together");
  cmd->add_option("--shard-by", o->shard_by, "probe | line: how --shard splits (default: the config's daemon.shard.by)")
      ->check(CLI::IsMember({"probe", "line"}));
  cmd->callback([o] {
    const Config config = load_config_or_exit(o->config);
    const ShardSpec shard = o->shard.empty() ? ShardSpec{} : parse_shard(o->shard, o->shard_by, config);
    if (o->shard.empty() && !o->shard_by.empty()) throw CLI::ValidationError("--shard-by", "needs --shard I/N");
    refuse_output_over_inputs("invert", "--out", o->out, {{"the input log", o->in}, {"the config", o->config}});
    BackendChoice choice =
        make_backend(o->backend.empty() ? config.daemon.backend : o->backend, config.daemon.cpu_threads);
    std::cerr << "tipforce invert: " << choice.note << "\n";
    lcmio::WindowProcessor processor(config, *choice.backend);
    // Count the windows first (for the progress bar and the empty-log check), then read the log
    // again from the start. Damage is reported once, in the second pass.
    std::int64_t total = 0, events = 0, damaged_bytes = 0;
    try {
      lcmio::LogReader counting(o->in);
      while (auto ev = counting.next()) {
        ++events;
        if (ev->channel == config.daemon.window_channel) ++total;
      }
      for (const lcmio::LogDamage& d : counting.take_damage()) damaged_bytes += static_cast<std::int64_t>(d.bytes);
    } catch (const lcmio::LogError& e) {
      std::cerr << "tipforce invert: " << e.what() << "\n";
      throw CLI::RuntimeError(2);
    }
    // A log damaged from its first window on (cut short, say) is damaged input, not an empty one:
    // the second pass reports where and exits 3, as tipforced does with the same log. A file with
    // no intact event that does not even start like an LCM log is another file given by mistake.
    if (total == 0 && (damaged_bytes == 0 || (events == 0 && !lcmio::starts_with_sync_word(o->in)))) {
      std::cerr << "tipforce invert: " << o->in << ": no windows on channel " << config.daemon.window_channel
                << " (empty, not an LCM log, or another channel"
                << (damaged_bytes > 0 ? "; " + std::to_string(damaged_bytes) + " bytes hold no LCM event" : "")
                << ")\n";
      throw CLI::RuntimeError(2);
    }
    std::unique_ptr<lcmio::LogWriter> out;
    std::unique_ptr<lcmio::LogReader> reread;
    try {
      reread = std::make_unique<lcmio::LogReader>(o->in);
      // The writer checks once more, on the opened file, that it is not the input.
      out = std::make_unique<lcmio::LogWriter>(o->out, /*append=*/false, &reread->identity());
    } catch (const lcmio::LogError& e) {
      std::cerr << "tipforce invert: " << e.what() << "\n";
      throw CLI::RuntimeError(2);
    }
    std::vector<double> solve_us;
    std::int64_t windows = 0, rejected = 0, unattributable = 0, not_converged = 0, write_errors = 0, other_shards = 0,
                 commands = 0;
    std::vector<uint8_t> buf;
    Progress progress("invert");
    const auto t0 = std::chrono::steady_clock::now();
    while (true) {
      std::optional<lcmio::LogEvent> ev = reread->next();
      for (const lcmio::LogDamage& d : reread->take_damage())
        std::cerr << "\ntipforce invert: " << o->in << ": " << lcmio::describe(d) << "; reading on from the next intact event\n";
      if (!ev) break;
      // The scan's geometry (tipforce import) travels with the estimates, so that `tipforce map`
      // of the output knows the scan size.
      if (ev->channel == "TIPFORCE_SCAN" && !out->write(ev->channel, ev->timestamp, ev->data.data(), ev->data.size()))
        if (write_errors++ < 5) std::cerr << "\ntipforce invert: " << out->error() << "\n";
      if (ev->channel != config.daemon.window_channel) continue;
      if (lcmio::window_shard(ev->data.data(), ev->data.size(), shard) != shard.index) {
        ++other_shards;  // another shard's run answers it
        progress.update(windows + other_shards, total);
        continue;
      }
      ++windows;
      lcmio::ProcessedWindow r = processor.process(ev->data.data(), ev->data.size(), lcmio::now_utime());
      if (!r.estimate) {
        ++unattributable;
        ++rejected;
        std::cerr << "\ntipforce invert: window event " << ev->eventnum << " rejected: " << r.reason << "\n";
        continue;
      }
      if (r.rejected) {
        ++rejected;
        std::cerr << "\ntipforce invert: window seq " << r.estimate->seq << " rejected: " << r.reason << "\n";
      } else {
        solve_us.push_back(r.solve_seconds * 1e6);
        if (r.estimate->status == force_estimate_t::STATUS_NOT_CONVERGED) ++not_converged;
      }
      buf.resize(static_cast<std::size_t>(r.estimate->getEncodedSize()));
      r.estimate->encode(buf.data(), 0, static_cast<int>(buf.size()));
      if (!out->write(config.daemon.estimate_channel, r.estimate->publish_utime, buf.data(), buf.size())) {
        // Reported for the first few, counted for all: the exit status says the output is incomplete.
        if (write_errors++ < 5) std::cerr << "\ntipforce invert: " << out->error() << "\n";
      }
      // A probe with an advisor: what it would have commanded (issue 13), as tipforced publishes it.
      if (auto command = processor.advise_last()) {
        ++commands;
        buf.resize(static_cast<std::size_t>(command->getEncodedSize()));
        command->encode(buf.data(), 0, static_cast<int>(buf.size()));
        if (!out->write(config.daemon.setpoint_channel, command->publish_utime, buf.data(), buf.size()))
          if (write_errors++ < 5) std::cerr << "\ntipforce invert: " << out->error() << "\n";
      }
      progress.update(windows + other_shards, total);
    }
    if (!out->close() && write_errors == 0) {
      ++write_errors;
      std::cerr << "tipforce invert: " << out->error() << "\n";
    }
    progress.finish();
    const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    // Percentiles of no solve are NaN; "p50 nan us" read like a measurement.
    char latency[96] = "no window solved";
    if (!solve_us.empty())
      std::snprintf(latency, sizeof latency, "solve latency p50 %.0f us p99 %.0f us", percentile(solve_us, 0.5),
                    percentile(solve_us, 0.99));
    std::printf("windows %lld, %.1f windows/s, %s, not converged %lld, rejected %lld"
                " (unattributable %lld), damaged input stretches %lld, write errors %lld\n",
                static_cast<long long>(windows), windows / std::max(secs, 1e-9), latency,
                static_cast<long long>(not_converged), static_cast<long long>(rejected),
                static_cast<long long>(unattributable), static_cast<long long>(reread->damaged_stretches()),
                static_cast<long long>(write_errors));
    if (commands > 0) std::printf("setpoint commands %lld\n", static_cast<long long>(commands));
    if (shard.sharded())
      std::printf("shard %s: %lld windows of the other shards left to them\n", shard.describe().c_str(),
                  static_cast<long long>(other_shards));
    std::fflush(stdout);
    // Exit codes as tipforced's: 1 output incomplete or input unreadable, 3 damaged input skipped.
    if (write_errors > 0 || !reread->error().empty()) {
      if (!reread->error().empty()) std::cerr << "tipforce invert: " << reread->error() << "\n";
      throw CLI::RuntimeError(1);
    }
    // Every window of this run rejected: the estimates log holds no estimate at all, only the
    // reasons. Exit 0 (or 3, "every readable window was answered") would say the run gave
    // something to use; the windows are unusable with this config (another probe, a drive
    // absurd for it), which is bad input.
    if (windows > 0 && rejected == windows) {
      std::cerr << "tipforce invert: " << o->in << ": every one of the " << windows
                << " windows was rejected (reasons above); no window was solved, " << o->out
                << " holds only the rejections\n";
      throw CLI::RuntimeError(2);
    }
    if (reread->damaged_stretches() > 0) throw CLI::RuntimeError(3);
  });
}

}  // namespace tipforce::cli
