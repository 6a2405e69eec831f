// tipforced: the tipforce streaming service. Command line, logging set-up, configuration and
// backend; the service itself is in daemon.cpp.
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <memory>
#include <string>

#include <CLI/CLI.hpp>
#include <spdlog/sinks/stdout_sinks.h>
#include <spdlog/spdlog.h>

#include "daemon.hpp"
#include "tipforce/backend.hpp"
#include "tipforce/config.hpp"
#include "tipforce/process_memory.hpp"
#include "tipforce/shard.hpp"

#ifndef TIPFORCE_VERSION
#define TIPFORCE_VERSION "unknown"
#endif

namespace {

// Exit codes: 0 clean stop, nothing lost; 1 runtime failure (input failed, output not written);
// 2 bad command line, configuration or set-up; 3 (kExitInputDamaged) damaged input log skipped.
constexpr int kExitRuntime = 1;
constexpr int kExitConfig = 2;

void setup_logging(const std::string& level) {
  auto logger = spdlog::stderr_logger_mt("tipforced");
  // Under systemd the journal stamps every line already.
  if (std::getenv("JOURNAL_STREAM") != nullptr)
    logger->set_pattern("[%l] %v");
  else
    logger->set_pattern("%Y-%m-%d %H:%M:%S.%e [%l] %v");
  spdlog::set_default_logger(logger);
  spdlog::set_level(spdlog::level::from_str(level));
  spdlog::flush_on(spdlog::level::warn);
}

}  // namespace

int main(int argc, char** argv) {
  // Before anything else. A log pipe that closes (`tipforced ... 2>&1 | head`) is a write error
  // that spdlog ignores, not a death by SIGPIPE in the middle of a scan. And a stop signal during
  // start-up waits (blocked) for the IO loop, so it ends in a clean stop with final stats.
  std::signal(SIGPIPE, SIG_IGN);
  tipforce::daemon::set_stop_signals_blocked(true);
  // Every window's buffers reused, not faulted in afresh (a cold search's batch 2-6 ms instead
  // of ~0.9 ms): process_memory.hpp.
  tipforce::keep_freed_memory_in_process();
  CLI::App app{"tipforced: estimates AFM tip-sample forces from deflection windows received over LCM"};
  std::string config_path;
  std::string input_url;
  std::string output_url;
  std::string backend_name;
  std::string log_level = "info";
  int shard_index = 0;
  app.add_option("-c,--config", config_path, "configuration file (TOML)")->required();
  auto* in_opt = app.add_option("--input-url", input_url, "LCM URL to subscribe on (overrides daemon.input_url)");
  auto* out_opt = app.add_option("--output-url", output_url, "LCM URL to publish on (overrides daemon.output_url)");
  app.add_option("--backend", backend_name, "forward backend (overrides daemon.backend)")
      ->check(CLI::IsMember({"auto", "cpu", "cuda"}));
  auto* shard_opt = app.add_option("--shard-index", shard_index,
                                   "this daemon's shard, 0 .. daemon.shard.count - 1 (overrides daemon.shard.index; "
                                   "systemd's tipforced@N.service passes N)");
  app.add_option("--log-level", log_level, "trace, debug, info, warn, error, critical or off")
      ->check(CLI::IsMember({"trace", "debug", "info", "warn", "warning", "error", "err", "critical", "off"}));
  app.set_version_flag("--version", std::string("tipforced ") + TIPFORCE_VERSION);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e) == 0 ? 0 : kExitConfig;
  }
  if (log_level == "warning") log_level = "warn";
  if (log_level == "error") log_level = "err";
  setup_logging(log_level);

  tipforce::Config config;
  try {
    config = tipforce::load_config(config_path);
  } catch (const tipforce::ConfigError& e) {
    spdlog::critical("configuration error: {}", e.what());
    return kExitConfig;
  } catch (const std::exception& e) {
    spdlog::critical("cannot load configuration {}: {}", config_path, e.what());
    return kExitConfig;
  }
  if (in_opt->count() > 0) config.daemon.input_url = input_url;
  if (out_opt->count() > 0) config.daemon.output_url = output_url;
  if (!backend_name.empty()) config.daemon.backend = backend_name;
  if (shard_opt->count() > 0) {
    // One configuration for every shard; the index comes from the command line (the template unit).
    if (!config.daemon.shard.sharded()) {
      spdlog::critical("--shard-index {}: {} has no daemon.shard table (e.g. shard = {{ count = 2, by = \"line\" }}), "
                       "so there is only shard 0",
                       shard_index, config_path);
      return kExitConfig;
    }
    config.daemon.shard.index = shard_index;
    if (const std::string problem = tipforce::shard_problem(config.daemon.shard); !problem.empty()) {
      spdlog::critical("--shard-index {}: {} (daemon.shard.count is {} in {})", shard_index, problem,
                       config.daemon.shard.count, config_path);
      return kExitConfig;
    }
  }

  tipforce::BackendChoice backend;
  try {
    backend = tipforce::make_backend(config.daemon.backend, config.daemon.cpu_threads);
  } catch (const std::exception& e) {
    spdlog::critical("backend \"{}\": {}", config.daemon.backend, e.what());
    return kExitConfig;
  }

  std::unique_ptr<tipforce::daemon::Daemon> service;
  try {
    tipforce::daemon::DaemonOptions options;
    options.config_path = config_path;
    options.version = TIPFORCE_VERSION;
    options.backend_note = backend.note;
    service = std::make_unique<tipforce::daemon::Daemon>(config, *backend.backend, std::move(options));
  } catch (const tipforce::ConfigError& e) {
    spdlog::critical("configuration error: {}", e.what());
    return kExitConfig;
  } catch (const std::exception& e) {
    spdlog::critical("cannot start: {}", e.what());
    return kExitConfig;
  }

  int code = kExitRuntime;
  try {
    code = service->run();
  } catch (const std::exception& e) {
    spdlog::critical("tipforced failed: {}", e.what());
    code = kExitRuntime;
  }
  spdlog::default_logger()->flush();
  if (service->must_abandon_solver()) {
    // The solver thread is still inside one inversion and cannot be interrupted; the output is
    // closed and the final stats are out, so leave without unwinding what it still uses.
    std::fflush(nullptr);
    std::_Exit(code);
  }
  service.reset();
  return code;
}
