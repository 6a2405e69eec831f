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
#include "commands.hpp"
#include "tipforce/event_log.hpp"
#include "tipforce/lcm_convert.hpp"
#include "tipforce/scan_geometry_t.hpp"
#include "tipforce/tipforce.hpp"

namespace tipforce::cli {
namespace {

struct Scan {
  double sample_period_s = 1e-7;
  int samples_per_window = 4000;
  int pixels_x = 1, pixels_y = 1;
  std::string start = "rest";
  // How each later line's first window is marked: "continued" (the trajectory is one, and says
  // so) or "unknown" (as an acquisition marks the pixel after its retrace: a cold start).
  std::string line_start = "continued";
  double noise_m = 0.0;
  std::uint64_t seed = 1;
  double scan_size_x_m = 0, scan_size_y_m = 0;  // 0: unknown (no scan_geometry_t written)
  Drive drive;
  // parameter -> pixels_y x pixels_x values (row-major)
  std::map<std::string, std::vector<double>> truth;
};

[[noreturn]] void fail(const std::string& where, const std::string& what) {
  std::cerr << "tipforce simulate: " << where << ": " << what << "\n";
  throw CLI::RuntimeError(2);
}

std::vector<double> read_csv_grid(const std::filesystem::path& path, int nx, int ny, const std::string& key) {
  std::ifstream in(path);
  if (!in) fail(path.string(), "cannot read the CSV given for " + key);
  std::vector<double> v;
  std::string line;
  int rows = 0;
  while (std::getline(in, line)) {
    if (line.empty()) continue;
    std::stringstream ss(line);
    std::string cell;
    int cols = 0;
    while (std::getline(ss, cell, ',')) {
      try {
        v.push_back(std::stod(cell));
      } catch (...) {
        fail(path.string(), "row " + std::to_string(rows + 1) + ": '" + cell + "' is not a number");
      }
      ++cols;
    }
    if (cols != nx) fail(path.string(), "row " + std::to_string(rows + 1) + " has " + std::to_string(cols) + " values, pixels_x is " + std::to_string(nx));
    ++rows;
  }
  if (rows != ny) fail(path.string(), "has " + std::to_string(rows) + " rows, pixels_y is " + std::to_string(ny));
  return v;
}

Scan read_scan(const std::string& path) {
  toml::table t;
  try {
    t = toml::parse_file(path);
  } catch (const toml::parse_error& e) {
    fail(path, "line " + std::to_string(e.source().begin.line) + ": " + std::string(e.description()));
  }
  Scan s;
  auto num = [&](const toml::node* n, const std::string& key) {
    if (auto d = n->value<double>()) return *d;
    fail(path, key + ": expected a number");
  };
  for (auto&& [k, v] : t) {
    const std::string key(k.str());
    if (key == "sample_period_s") s.sample_period_s = num(&v, key);
    else if (key == "samples_per_window") s.samples_per_window = static_cast<int>(num(&v, key));
    else if (key == "pixels_x") s.pixels_x = static_cast<int>(num(&v, key));
    else if (key == "pixels_y") s.pixels_y = static_cast<int>(num(&v, key));
    else if (key == "start") s.start = v.value<std::string>().value_or("?");
    else if (key == "line_start") s.line_start = v.value<std::string>().value_or("?");
    else if (key == "noise_m") s.noise_m = num(&v, key);
    else if (key == "seed") s.seed = static_cast<std::uint64_t>(num(&v, key));
    else if (key == "scan_size_m") {
      // [x, y] in metres, or one number for square pixels: written as a scan_geometry_t so that
      // `tipforce map` draws physical axes.
      if (auto* a = v.as_array(); a && (a->size() == 1 || a->size() == 2)) {
        s.scan_size_x_m = num(a->get(0), key);
        s.scan_size_y_m = a->size() == 2 ? num(a->get(1), key) : 0;
      } else {
        s.scan_size_x_m = num(&v, key);
      }
      if (!(s.scan_size_x_m > 0) || !(s.scan_size_y_m >= 0)) fail(path, key + ": must be positive metres");
    }
    else if (key != "drive" && key != "truth") fail(path, key + ": unknown key");
  }
  if (!(s.sample_period_s > 0)) fail(path, "sample_period_s: must be positive");
  if (s.samples_per_window < 3 || s.samples_per_window > kMaxWindowSamples) fail(path, "samples_per_window: must be in [3, 1000000]");
  if (s.pixels_x < 1 || s.pixels_y < 1) fail(path, "pixels_x, pixels_y: must be at least 1");
  if (s.scan_size_x_m > 0 && s.scan_size_y_m == 0) s.scan_size_y_m = s.scan_size_x_m * s.pixels_y / s.pixels_x;
  if (s.start != "rest" && s.start != "steady") fail(path, "start: must be \"rest\" or \"steady\"");
  if (s.line_start != "continued" && s.line_start != "unknown")
    fail(path, "line_start: must be \"continued\" or \"unknown\"");
  if (!(s.noise_m >= 0)) fail(path, "noise_m: must be >= 0");
  if (auto* d = t["drive"].as_table()) {
    for (auto&& [k, v] : *d) {
      const std::string key = "drive." + std::string(k.str());
      const std::string_view n = k.str();
      if (n == "kind") {
        const std::string kind = v.value<std::string>().value_or("?");
        if (kind == "sine") s.drive.kind = DriveKind::sine;
        else if (kind == "chirp") s.drive.kind = DriveKind::chirp;
        else fail(path, key + ": must be \"sine\" or \"chirp\"");
      } else if (n == "amplitude_m") s.drive.amplitude_m = num(&v, key);
      else if (n == "frequency_hz") s.drive.frequency_hz = num(&v, key);
      else if (n == "phase_rad") s.drive.phase_rad = num(&v, key);
      else if (n == "chirp_hz_per_s") s.drive.chirp_hz_per_s = num(&v, key);
      else fail(path, key + ": unknown key");
    }
  }
  const std::filesystem::path dir = std::filesystem::path(path).parent_path();
  if (auto* tr = t["truth"].as_table()) {
    for (auto&& [k, v] : *tr) {
      const std::string key(k.str());
      const int n = s.pixels_x * s.pixels_y;
      if (auto d = v.value<double>()) s.truth[key].assign(static_cast<std::size_t>(n), *d);
      else if (auto f = v.value<std::string>())
        s.truth[key] = read_csv_grid(std::filesystem::path(*f).is_absolute() ? std::filesystem::path(*f) : dir / *f,
                                     s.pixels_x, s.pixels_y, "truth." + key);
      else fail(path, "truth." + key + ": expected a number or a CSV file name");
    }
  }
  return s;
}

}  // namespace

void add_simulate_command(CLI::App& app) {
  auto* cmd = app.add_subcommand("simulate", "Simulate a scan: one deflection window per pixel, as an LCM log");
  struct Opts {
    std::string config, probe, scan, out, integrator = "reference", channel;
  };
  auto o = std::make_shared<Opts>();
  cmd->add_option("--config", o->config, "Config file (TOML)")->required()->check(CLI::ExistingFile);
  cmd->add_option("--probe", o->probe, "Probe name")->required();
  cmd->add_option("--scan", o->scan, "Scan description (TOML)")->required()->check(CLI::ExistingFile);
  cmd->add_option("--out", o->out, "Output LCM log; the truth goes to OUT.truth.csv")->required();
  cmd->add_option("--integrator", o->integrator, "reference (adaptive Dormand-Prince, independent of the inversion) or fast")
      ->check(CLI::IsMember({"reference", "fast"}));
  cmd->add_option("--channel", o->channel, "Channel (default: the config's window_channel)");
  cmd->callback([o] {
    const Config config = load_config_or_exit(o->config);
    if (!config.probes.count(o->probe)) fail(o->config, "probe." + o->probe + ": no such probe in the config");
    const ProbeModel probe = config.probe_model(o->probe);
    const Scan scan = read_scan(o->scan);
    const ParameterSpace& space = probe.space;
    const auto model_names = force_model_parameters(space.model());
    // Every model parameter comes from the truth table, or from the config's fixed value.
    std::vector<std::string> truth_names;
    for (auto n : model_names) {
      const std::string name(n);
      if (scan.truth.count(name)) truth_names.push_back(name);
    }
    for (const auto& [name, _] : scan.truth)
      if (space.index_of(name) < 0 || ParameterLayout(space.model()).is_drive(space.index_of(name)))
        fail(o->scan, "truth." + name + ": not a parameter of model " + std::string(to_string(space.model())));
    std::vector<double> fixed_full(static_cast<std::size_t>(space.n_full()));
    Window proto;
    proto.drive = scan.drive;
    proto.sample_period_s = scan.sample_period_s;
    {
      std::vector<double> unknown_mid;
      for (int j = 0; j < space.n_unknowns(); ++j) unknown_mid.push_back(std::nan(""));
      space.assemble(proto, unknown_mid.data(), fixed_full.data());
    }
    for (std::size_t i = 0; i < model_names.size(); ++i)
      if (std::isnan(fixed_full[i]) && !scan.truth.count(std::string(model_names[i])))
        fail(o->scan, "truth." + std::string(model_names[i]) + ": missing (it is not fixed in the config)");

    auto backend = make_cpu_backend();
    if (std::filesystem::exists(o->scan) && lcmio::same_file(o->scan, o->out))
      fail(o->out, "is the scan file; choose another output");
    std::unique_ptr<lcmio::LogWriter> log;
    try {
      log = std::make_unique<lcmio::LogWriter>(o->out, /*append=*/false);
    } catch (const lcmio::LogError& e) {
      fail(o->out, e.what());
    }
    std::ofstream truth_csv(o->out + ".truth.csv");
    truth_csv << "seq,pixel_x,pixel_y";
    for (const auto& n : truth_names) truth_csv << "," << n;
    truth_csv << "\n";
    truth_csv.precision(10);
    const std::string channel = o->channel.empty() ? config.daemon.window_channel : o->channel;
    std::mt19937_64 rng(scan.seed);
    std::normal_distribution<double> noise(0.0, scan.noise_m > 0 ? scan.noise_m : 1.0);
    const int M = probe.modal.n_modes(), N = scan.samples_per_window;
    const double dt = scan.sample_period_s;
    ModalState state = ModalState::rest(M);
    auto params_at = [&](int pixel) {
      std::vector<double> full = fixed_full;
      for (std::size_t i = 0; i < model_names.size(); ++i) {
        auto it = scan.truth.find(std::string(model_names[i]));
        if (it != scan.truth.end()) full[i] = it->second[static_cast<std::size_t>(pixel)];
      }
      const ParameterLayout layout(space.model());
      full[layout.drive_index(DriveParameter::amplitude_m)] = scan.drive.amplitude_m;
      full[layout.drive_index(DriveParameter::frequency_hz)] = scan.drive.frequency_hz;
      full[layout.drive_index(DriveParameter::phase_rad)] = scan.drive.phase_rad;
      full[layout.drive_index(DriveParameter::chirp_hz_per_s)] = scan.drive.chirp_hz_per_s;
      return full;
    };
    if (scan.start == "steady") {
      // Run in from the drive's linear steady state for six decay times of mode 1.
      const double tau = 2 * probe.modal.modes()[0].quality_factor / probe.modal.modes()[0].omega_rad_per_s;
      const int lead = static_cast<int>(6 * tau / dt);
      Window w = proto;
      w.t0_s = -lead * dt;
      w.deflection_m.assign(static_cast<std::size_t>(lead), 0.0);
      state = linear_steady_state(probe.modal, scan.drive.amplitude_m, scan.drive.frequency_hz, scan.drive.phase_rad, w.t0_s);
      state = reference_simulate(probe.modal, space.model(), w, params_at(0), state).end_state;
    }
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
      if (!log->write("TIPFORCE_SCAN", utime0, buf.data(), buf.size())) fail("--out", log->error());
    }
    Progress progress("simulate");
    for (int px = 0; px < pixels; ++px) {
      Window w = proto;
      w.t0_s = static_cast<double>(px) * N * dt;
      w.deflection_m.assign(static_cast<std::size_t>(N), 0.0);
      w.initial = px == 0 ? (scan.start == "rest" ? InitialState::rest : InitialState::unknown)
                  : px % scan.pixels_x == 0 && scan.line_start == "unknown" ? InitialState::unknown
                                                                          : InitialState::continued;
      const std::vector<double> full = params_at(px);
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
      if (!log->write(channel, h.utime, buf.data(), buf.size())) fail("--out", log->error());
      truth_csv << px << "," << h.pixel_x << "," << h.pixel_y;
      for (const auto& n : truth_names) truth_csv << "," << scan.truth.at(n)[static_cast<std::size_t>(px)];
      truth_csv << "\n";
      progress.update(px + 1, pixels);
    }
    progress.finish();
    if (!log->close()) fail("--out", log->error());
    truth_csv.flush();
    if (!truth_csv) fail(o->out + ".truth.csv", "write failed");
    std::cout << "wrote " << pixels << " windows of " << N << " samples to " << o->out << " (truth: " << o->out
              << ".truth.csv)\n";
  });
}

}  // namespace tipforce::cli
