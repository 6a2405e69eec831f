// `tipforce simulate`: a synthetic raster scan written as an LCM log, one window per pixel,
// windows contiguous in time, made by the independent reference integrator by default.
#include <toml++/toml.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <random>
#include <sstream>

#include "cli_common.hpp"
#include "scan_description.hpp"
#include "simulate_live.hpp"
#include "commands.hpp"
#include "tipforce/event_log.hpp"
#include "tipforce/lcm_convert.hpp"
#include "tipforce/scan_geometry_t.hpp"
#include "tipforce/tipforce.hpp"

namespace tipforce::cli {
namespace {

[[noreturn]] void fail(const std::string& where, const std::string& what) {
  std::cerr << "tipforce simulate: " << where << ": " << what << "\n";
  throw CLI::RuntimeError(2);
}

// An output that could not be written: exit 1, as tipforce invert (2 is for bad input).
[[noreturn]] void write_failed(const std::string& where, const std::string& what) {
  std::cerr << "tipforce simulate: " << where << ": " << what << "\n";
  throw CLI::RuntimeError(1);
}

// Whether path is /dev/null (any spelling or link to it): an output the user discards.
bool is_null_device(const std::string& path) { return lcmio::same_file(path, "/dev/null"); }

// The truth table's path: --truth, else OUT.truth.csv beside a log file. An --out that is no
// regular file gives no place beside it: /dev/null (a dry run) discards the truth as well (its
// default used to be /dev/null.truth.csv, a file in /dev or a write error), and any other (a
// FIFO, a terminal) needs --truth.
std::string truth_table_path(const std::string& out, const std::string& truth) {
  if (!truth.empty()) return truth;
  if (is_null_device(out)) return out;
  std::error_code ec;
  const auto st = std::filesystem::status(out, ec);
  if (!ec && std::filesystem::exists(st) && !std::filesystem::is_regular_file(st))
    fail(out, "--out is not a regular file, so there is no OUT.truth.csv beside it: name the truth table with "
              "--truth (/dev/null to discard it)");
  return out + ".truth.csv";
}

}  // namespace

void add_simulate_command(CLI::App& app) {
  auto* cmd = app.add_subcommand("simulate", "Simulate a scan: one deflection window per pixel, as an LCM log");
  struct Opts {
    std::string config, probe, scan, out, truth, integrator = "reference", channel;
    bool live = false;
  };
  auto o = std::make_shared<Opts>();
  auto live = std::make_shared<LiveOptions>();
  cmd->add_option("--config", o->config, "Config file (TOML)")->required()->check(CLI::ExistingFile);
  cmd->add_option("--probe", o->probe, "Probe name")->required();
  cmd->add_option("--scan", o->scan, "Scan description (TOML)")->required()->check(CLI::ExistingFile);
  cmd->add_option("--out", o->out, "Output LCM log; the truth goes to OUT.truth.csv or --truth (--live: the truth CSV itself)")
      ->required();
  auto* truth_option = cmd->add_option("--truth", o->truth, "Where the truth table goes (default OUT.truth.csv)");
  auto* integrator = cmd->add_option("--integrator", o->integrator, "reference (adaptive Dormand-Prince, independent of the inversion) or fast")
      ->check(CLI::IsMember({"reference", "fast"}));
  cmd->add_option("--channel", o->channel, "Channel (default: the config's window_channel)");
  // The simulated microscope (issue 13): windows published over LCM, in lock-step with the answers.
  auto* live_flag = cmd->add_flag("--live", o->live,
                "A simulated microscope: publish each window over LCM, wait for its answer (--lockstep), obey the "
                "setpoints it receives from the next pixel on, record the true peak force per pixel in --out");
  // The simulated microscope is the reference integrator's: what tipforced fits must not be its own model.
  integrator->excludes(live_flag);
  truth_option->excludes(live_flag);  // --live's --out is the truth table
  cmd->add_option("--lcm-url", live->lcm_url, "--live: LCM URL (default: LCM's)")->needs(live_flag);
  cmd->add_option("--lockstep", live->lockstep,
                  "--live: wait for each window's estimate (open loop) or the controller's instrument_setpoint_t "
                  "(closed loop)")
      ->check(CLI::IsMember({"estimate", "instrument"}))
      ->needs(live_flag);
  cmd->add_option("--instrument-channel", live->instrument_channel, "--live: where the setpoints come from")
      ->needs(live_flag);
  cmd->add_option("--timeout-s", live->timeout_s, "--live: how long to wait for an answer")
      ->check(CLI::PositiveNumber)
      ->needs(live_flag);
  cmd->callback([o, live] {
    const Config config = load_config_or_exit(o->config);
    if (!config.probes.count(o->probe)) fail(o->config, "probe." + o->probe + ": no such probe in the config");
    const ProbeModel probe = config.probe_model(o->probe);
    const Scan scan = read_scan(o->scan);
    const ParameterSpace& space = probe.space;
    const ScanTruth truth(scan, probe, o->scan);
    check_scan_windows_for_probe(scan, probe, o->scan);
    std::vector<NamedInput> inputs = {{"the config", o->config}, {"the scan description", o->scan}};
    for (const std::string& csv : scan.truth_files) inputs.push_back({"a truth CSV of the scan", csv});
    refuse_output_over_inputs("simulate", "--out", o->out, inputs);
    std::string truth_path;  // --live: --out is the truth table
    if (!o->live) {
      truth_path = truth_table_path(o->out, o->truth);
      refuse_output_over_inputs("simulate", "--truth", truth_path, inputs);
      if (!o->truth.empty() && !is_null_device(truth_path) && lcmio::same_file(truth_path, o->out))
        fail(truth_path, "--truth is --out: the truth table would overwrite the log");
    }
    const std::vector<std::string>& truth_names = truth.names();
    Window proto;
    proto.drive = scan.drive;
    proto.sample_period_s = scan.sample_period_s;
    if (o->live) {
      live->config_path = o->config;
      live->probe = o->probe;
      live->channel = o->channel.empty() ? config.daemon.window_channel : o->channel;
      live->estimate_channel = config.daemon.estimate_channel;
      live->truth_csv = o->out;
      run_live_simulation(*live, probe, scan, truth);
      return;
    }
    auto backend = make_cpu_backend();
    // The run-in first: a failure or an interrupt there leaves no empty log behind.
    ModalState state = scan_start_state(scan, probe, truth.full_at(0));
    // The truth table before the log: a --truth that cannot be written fails here, not after the
    // whole scan with a log left behind.
    std::ofstream truth_csv(truth_path);
    if (!truth_csv) write_failed(truth_path, "cannot open the truth table for writing");
    std::unique_ptr<lcmio::LogWriter> log;
    try {
      log = std::make_unique<lcmio::LogWriter>(o->out, /*append=*/false);
    } catch (const lcmio::LogError& e) {
      write_failed(o->out, e.what());
    }
    truth_csv << "seq,pixel_x,pixel_y";
    for (const auto& n : truth_names) truth_csv << "," << n;
    truth_csv << "\n";
    truth_csv.precision(10);
    const std::string channel = o->channel.empty() ? config.daemon.window_channel : o->channel;
    std::mt19937_64 rng(scan.seed);
    std::normal_distribution<double> noise(0.0, scan.noise_m > 0 ? scan.noise_m : 1.0);
    const int N = scan.samples_per_window;
    const double dt = scan.sample_period_s;
    const int pixels = scan.pixels_x * scan.pixels_y;
    const std::int64_t utime0 = 1'700'000'000'000'000;
    if (scan.scan_size_x_m > 0) {
      scan_geometry_t g;
      g.utime = utime0;
      g.probe = o->probe;
      g.pixels_x = scan.pixels_x;
      g.pixels_y = scan.pixels_y;
      g.size_x_m = scan.scan_size_x_m;
      g.size_y_m = scan.scan_size_y_m;
      g.direction = scan_geometry_t::DIRECTION_TRACE;
      g.source = "tipforce simulate " + o->scan;
      std::vector<uint8_t> buf(static_cast<std::size_t>(g.getEncodedSize()));
      g.encode(buf.data(), 0, static_cast<int>(buf.size()));
      if (!log->write("TIPFORCE_SCAN", utime0, buf.data(), buf.size())) write_failed("--out", log->error());
    }
    Progress progress("simulate");
    for (int px = 0; px < pixels; ++px) {
      Window w = proto;
      w.t0_s = static_cast<double>(px) * N * dt;
      w.deflection_m.assign(static_cast<std::size_t>(N), 0.0);
      w.initial = scan_initial_state(scan, px);
      const std::vector<double> full = truth.full_at(px);
      std::vector<double> signal;
      if (o->integrator == "reference") {
        ReferenceResult r = reference_simulate(probe.modal, space.model(), w, full, state);
        signal = std::move(r.signal);
        state = r.end_state;
      } else {
        ForwardOutput f = simulate_one(*backend, probe.modal, space.model(), w, full, state);
        signal = std::move(f.signal);
        state = f.end_state[0];
      }
      for (int i = 0; i < N; ++i) w.deflection_m[i] = signal[i] + (scan.noise_m > 0 ? noise(rng) : 0.0);
      lcmio::WindowHeader h;
      h.probe = o->probe;
      h.seq = px;
      h.pixel_x = px % scan.pixels_x;
      h.pixel_y = px / scan.pixels_x;
      h.utime = utime0 + static_cast<std::int64_t>(std::llround(w.t0_s * 1e6));
      const deflection_window_t msg = lcmio::to_message(h, w);
      std::vector<uint8_t> buf(static_cast<std::size_t>(msg.getEncodedSize()));
      msg.encode(buf.data(), 0, static_cast<int>(buf.size()));
      // The one event writer (lcmio::LogWriter): a full disk fails here, not silently.
      if (!log->write(channel, h.utime, buf.data(), buf.size())) write_failed("--out", log->error());
      truth_csv << px << "," << h.pixel_x << "," << h.pixel_y;
      for (const auto& n : truth_names) truth_csv << "," << truth.value(n, px);
      truth_csv << "\n";
      progress.update(px + 1, pixels);
    }
    progress.finish();
    if (!log->close()) write_failed("--out", log->error());
    truth_csv.flush();
    if (!truth_csv) write_failed(truth_path, "write failed");
    std::cout << "wrote " << pixels << " windows of " << N << " samples to " << o->out << " (truth: " << truth_path
              << ")\n";
  });
}

}  // namespace tipforce::cli
