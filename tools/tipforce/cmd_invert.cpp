// `tipforce invert`: every window of a log, in order, through the same WindowProcessor tipforced
// uses, into an estimates log.
#include <lcm/lcm-cpp.hpp>

#include <chrono>
#include <cstdio>
#include <iostream>

#include "cli_common.hpp"
#include "commands.hpp"
#include "tipforce/backend.hpp"
#include "tipforce/window_processor.hpp"

namespace tipforce::cli {

void add_invert_command(CLI::App& app) {
  auto* cmd = app.add_subcommand("invert", "Invert every window of an LCM log into force estimates");
  struct Opts {
    std::string config, in, out, backend;
  };
  auto o = std::make_shared<Opts>();
  cmd->add_option("--config", o->config, "Config file (TOML)")->required()->check(CLI::ExistingFile);
  cmd->add_option("--in", o->in, "Input LCM log with windows")->required()->check(CLI::ExistingFile);
  cmd->add_option("--out", o->out, "Output LCM log with estimates")->required();
  cmd->add_option("--backend", o->backend, "auto | cpu | cuda (default: the config's)");
  cmd->callback([o] {
    const Config config = load_config_or_exit(o->config);
    BackendChoice choice = make_backend(o->backend.empty() ? config.daemon.backend : o->backend);
    std::cerr << "tipforce invert: " << choice.note << "\n";
    lcmio::WindowProcessor processor(config, *choice.backend);
    lcm::LogFile in(o->in, "r");
    if (!in.good()) {
      std::cerr << "tipforce invert: " << o->in << ": cannot read the log\n";
      throw CLI::RuntimeError(2);
    }
    // Count the windows first (for the progress bar), then read the log again from the start.
    std::int64_t total = 0;
    while (const lcm::LogEvent* ev = in.readNextEvent())
      if (ev->channel == config.daemon.window_channel) ++total;
    if (total == 0) {
      std::cerr << "tipforce invert: " << o->in << ": no windows on channel " << config.daemon.window_channel
                << " (empty, not an LCM log, or another channel)\n";
      throw CLI::RuntimeError(2);
    }
    lcm::LogFile out(o->out, "w");
    if (!out.good()) {
      std::cerr << "tipforce invert: " << o->out << ": cannot write the log\n";
      throw CLI::RuntimeError(2);
    }
    lcm::LogFile reread(o->in, "r");
    std::vector<double> solve_us;
    std::int64_t windows = 0, rejected = 0, unattributable = 0, not_converged = 0, eventnum = 0;
    Progress progress("invert");
    const auto t0 = std::chrono::steady_clock::now();
    while (const lcm::LogEvent* ev = reread.readNextEvent()) {
      if (ev->channel != config.daemon.window_channel) continue;
      ++windows;
      lcmio::ProcessedWindow r = processor.process(ev->data, static_cast<std::size_t>(ev->datalen), lcmio::now_utime());
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
      std::vector<uint8_t> buf(static_cast<std::size_t>(r.estimate->getEncodedSize()));
      r.estimate->encode(buf.data(), 0, static_cast<int>(buf.size()));
      lcm::LogEvent oe;
      oe.eventnum = eventnum++;
      oe.timestamp = r.estimate->publish_utime;
      oe.channel = config.daemon.estimate_channel;
      oe.datalen = static_cast<int32_t>(buf.size());
      oe.data = buf.data();
      out.writeEvent(&oe);
      progress.update(windows, total);
    }
    progress.finish();
    const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    std::printf("windows %lld, %.1f windows/s, solve latency p50 %.0f us p99 %.0f us, not converged %lld, rejected %lld"
                " (unattributable %lld)\n",
                static_cast<long long>(windows), windows / std::max(secs, 1e-9), percentile(solve_us, 50),
                percentile(solve_us, 99), static_cast<long long>(not_converged), static_cast<long long>(rejected),
                static_cast<long long>(unattributable));
  });
}

}  // namespace tipforce::cli
