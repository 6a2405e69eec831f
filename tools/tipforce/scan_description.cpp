// A synthetic scan's description: reading scan.toml, the truth per pixel, the steady start.
#include "scan_description.hpp"

#include <toml++/toml.h>

#include <charconv>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <sstream>

#include <CLI/CLI.hpp>

#include "tipforce/config.hpp"
#include "tipforce/window.hpp"

namespace tipforce::cli {
namespace {


[[noreturn]] void fail(const std::string& where, const std::string& what) {
  std::cerr << "tipforce simulate: " << where << ": " << what << "\n";
  throw CLI::RuntimeError(2);
}

// A number filling the whole cell (spaces around it allowed); inf and nan parse, and the
// truth's range check refuses them with their pixel.
bool parse_cell(const std::string& cell, double& v) {
  const auto b = cell.find_first_not_of(" \t"), e = cell.find_last_not_of(" \t");
  if (b == std::string::npos) return false;
  const char* first = cell.data() + b + (cell[b] == '+' ? 1 : 0);
  const char* last = cell.data() + e + 1;
  const auto [end, ec] = std::from_chars(first, last, v);
  return ec == std::errc() && end == last;
}

std::vector<double> read_csv_grid(const std::filesystem::path& path, int nx, int ny, const std::string& key) {
  std::ifstream in(path);
  if (!in || std::filesystem::is_directory(path)) fail(path.string(), "cannot read the CSV given for " + key);
  std::vector<double> v;
  std::string line;
  int rows = 0, line_no = 0;
  while (std::getline(in, line)) {
    ++line_no;
    if (line_no == 1 && line.rfind("\xEF\xBB\xBF", 0) == 0) line.erase(0, 3);  // a UTF-8 byte order mark
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.find_first_not_of(" \t") == std::string::npos) continue;
    std::stringstream ss(line);
    std::string cell;
    int cols = 0;
    const std::string where = "line " + std::to_string(line_no) + " (row " + std::to_string(rows + 1) + ")";
    while (std::getline(ss, cell, ',')) {
      double x = 0;
      // The whole cell (stod read "3abc" as 3 and "0x1" as 1; the map's truth reader refused them).
      if (!parse_cell(cell, x)) fail(path.string(), where + ": '" + cell + "' is not a number");
      v.push_back(x);
      ++cols;
    }
    if (cols != nx)
      fail(path.string(), where + " has " + std::to_string(cols) + " values, pixels_x is " + std::to_string(nx));
    ++rows;
  }
  if (rows != ny) fail(path.string(), "has " + std::to_string(rows) + " rows, pixels_y is " + std::to_string(ny));
  return v;
}

}  // namespace

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
  // A count: a whole number in [lo, hi] (a cast let 4.5 through as 4 and 2^31 wrap negative).
  // `why` says where a bound comes from when it is another program's.
  auto whole = [&](const toml::node* n, const std::string& key, double lo, double hi, const std::string& why = "") {
    const double d = num(n, key);
    if (!(d >= lo && d <= hi) || d != std::floor(d))
      fail(path, key + ": must be a whole number in [" + std::to_string(static_cast<long long>(lo)) + ", " +
                     std::to_string(static_cast<long long>(hi)) + "], got " + std::to_string(d) + (d < lo ? why : ""));
    return static_cast<int>(d);
  };
  // The readers' window sizes (window_problem_for_probe): a shorter window was written and then
  // rejected by tipforced and tipforce invert alike, so the log could not be inverted at all.
  const int min_window = WindowLimits{}.min_samples;
  const std::string window_why =
      ": tipforced and tipforce invert reject a window of fewer than " + std::to_string(min_window) + " samples";
  for (auto&& [k, v] : t) {
    const std::string key(k.str());
    if (key == "sample_period_s") s.sample_period_s = num(&v, key);
    else if (key == "samples_per_window") s.samples_per_window = whole(&v, key, min_window, kMaxWindowSamples, window_why);
    else if (key == "pixels_x") s.pixels_x = whole(&v, key, 1, 1 << 20);
    else if (key == "pixels_y") s.pixels_y = whole(&v, key, 1, 1 << 20);
    else if (key == "start") s.start = v.value<std::string>().value_or("?");
    else if (key == "line_start") s.line_start = v.value<std::string>().value_or("?");
    else if (key == "noise_m") s.noise_m = num(&v, key);
    else if (key == "seed") {
      // A whole number from 0 (a cast made 1.5 and 1.9 seed 1, -0.5 and 1e300 seed 0; 2^63 - 1 was
      // "not a number": a double cannot hold it, an integer can).
      if (auto i = v.value<std::int64_t>(); i && v.is_integer() && *i >= 0) {
        s.seed = static_cast<std::uint64_t>(*i);
      } else {
        const double d = num(&v, key);
        if (!(d >= 0 && d <= 9007199254740992.0) || d != std::floor(d)) {
          char got[32];
          std::snprintf(got, sizeof got, "%g", d);
          fail(path, key + ": must be a whole number from 0 (an integer up to 2^63 - 1), got " + got);
        }
        s.seed = static_cast<std::uint64_t>(d);
      }
    }
    else if (key == "scan_size_m") {
      // [x, y] in metres, or one number for square pixels: written as a scan_geometry_t so that
      // `tipforce map` draws physical axes.
      if (auto* a = v.as_array(); a && (a->size() == 1 || a->size() == 2)) {
        s.scan_size_x_m = num(a->get(0), key);
        s.scan_size_y_m = a->size() == 2 ? num(a->get(1), key) : 0;
      } else {
        s.scan_size_x_m = num(&v, key);
      }
      if (!(s.scan_size_x_m > 0) || !(s.scan_size_y_m >= 0) || !std::isfinite(s.scan_size_x_m + s.scan_size_y_m))
        fail(path, key + ": must be positive metres");
    }
    else if (key != "drive" && key != "truth") fail(path, key + ": unknown key");
  }
  if (!(s.sample_period_s > 0)) fail(path, "sample_period_s: must be positive");
  if (!sample_period_range().holds(s.sample_period_s))
    fail(path, "sample_period_s: must be " + std::string(sample_period_range().what) + ", got " + std::to_string(s.sample_period_s));
  if (s.samples_per_window < min_window || s.samples_per_window > kMaxWindowSamples)
    fail(path, "samples_per_window: must be in [" + std::to_string(min_window) + ", " + std::to_string(kMaxWindowSamples) +
                   "], got " + std::to_string(s.samples_per_window) + window_why);
  if (s.pixels_x < 1 || s.pixels_y < 1) fail(path, "pixels_x, pixels_y: must be at least 1");
  // Before the truth tables (pixels_x x pixels_y values each) are allocated.
  const std::int64_t pixels = std::int64_t{s.pixels_x} * s.pixels_y;
  if (pixels > kMaxScanPixels)
    fail(path, "pixels_x x pixels_y: " + std::to_string(s.pixels_x) + " x " + std::to_string(s.pixels_y) + " = " +
                   std::to_string(pixels) + " pixels, more than the " + std::to_string(kMaxScanPixels) +
                   " (4096 x 4096) tipforce simulate writes");
  if (pixels * s.samples_per_window > kMaxScanSamples)
    fail(path, "pixels_x x pixels_y x samples_per_window: " + std::to_string(pixels) + " x " +
                   std::to_string(s.samples_per_window) + " = " + std::to_string(pixels * s.samples_per_window) +
                   " samples, more than the " + std::to_string(kMaxScanSamples) +
                   " (4096 x 4096 windows of 2048 samples, 128 GiB) tipforce simulate writes");
  if (s.scan_size_x_m > 0 && s.scan_size_y_m == 0) s.scan_size_y_m = s.scan_size_x_m * s.pixels_y / s.pixels_x;
  if (s.start != "rest" && s.start != "steady") fail(path, "start: must be \"rest\" or \"steady\"");
  if (s.line_start != "continued" && s.line_start != "unknown")
    fail(path, "line_start: must be \"continued\" or \"unknown\"");
  if (!(s.noise_m >= 0) || !std::isfinite(s.noise_m)) fail(path, "noise_m: must be a finite number >= 0, got " + std::to_string(s.noise_m));
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
  // The config's limits for the same quantities (a 1e12 Hz drive hung the simulation, 0 Hz or NaN
  // wrote windows that every reader rejects).
  const auto in_range = [&](const char* key, const char* parameter, double v) {
    const ValueRange r = parameter_value_range(parameter);
    if (!r.holds(v)) fail(path, std::string(key) + ": must be " + r.what + ", got " + std::to_string(v));
  };
  in_range("drive.amplitude_m", "drive_amplitude_m", s.drive.amplitude_m);
  in_range("drive.frequency_hz", "drive_frequency_hz", s.drive.frequency_hz);
  if (!(s.drive.frequency_hz > 0)) fail(path, "drive.frequency_hz: must be positive");
  in_range("drive.phase_rad", "drive_phase_rad", s.drive.phase_rad);
  in_range("drive.chirp_hz_per_s", "drive_chirp_hz_per_s", s.drive.chirp_hz_per_s);
  // The sine ignored it in the data but wrote it into every window (as tipforce import refuses).
  if (s.drive.kind == DriveKind::sine && s.drive.chirp_hz_per_s != 0)
    fail(path, "drive.chirp_hz_per_s: is for kind = \"chirp\" (the drive is a sine)");
  const std::filesystem::path dir = std::filesystem::path(path).parent_path();
  if (auto* tr = t["truth"].as_table()) {
    for (auto&& [k, v] : *tr) {
      const std::string key(k.str());
      const int n = s.pixels_x * s.pixels_y;
      if (auto d = v.value<double>()) s.truth[key].assign(static_cast<std::size_t>(n), *d);
      else if (auto f = v.value<std::string>()) {
        const std::filesystem::path csv = std::filesystem::path(*f).is_absolute() ? std::filesystem::path(*f) : dir / *f;
        s.truth[key] = read_csv_grid(csv, s.pixels_x, s.pixels_y, "truth." + key);
        s.truth_files.push_back(csv.string());
      }
      else fail(path, "truth." + key + ": expected a number or a CSV file name");
      // Every pixel's value within the config's limits for the parameter (a NaN cell corrupted
      // the windows after it through the continued state).
      const ValueRange r = parameter_value_range(key);
      const std::vector<double>& values = s.truth[key];
      for (std::size_t i = 0; i < values.size(); ++i)
        if (!r.holds(values[i]))
          fail(path, "truth." + key + ": pixel (" + std::to_string(i % static_cast<std::size_t>(s.pixels_x)) + ", " +
                         std::to_string(i / static_cast<std::size_t>(s.pixels_x)) + ") is " + std::to_string(values[i]) +
                         ", must be " + r.what);
    }
  }
  return s;
}


ScanTruth::ScanTruth(const Scan& scan, const ProbeModel& probe, const std::string& scan_path)
    : scan_(&scan), space_(probe.space) {
  const auto model_names = force_model_parameters(space_.model());
  for (auto n : model_names) {
    const std::string name(n);
    if (scan.truth.count(name)) names_.push_back(name);
  }
  for (const auto& [name, _] : scan.truth)
    if (space_.index_of(name) < 0 || ParameterLayout(space_.model()).is_drive(space_.index_of(name)))
      fail(scan_path, "truth." + name + ": not a parameter of model " + std::string(to_string(space_.model())));
  fixed_full_.assign(static_cast<std::size_t>(space_.n_full()), 0.0);
  Window proto;
  proto.drive = scan.drive;
  proto.sample_period_s = scan.sample_period_s;
  std::vector<double> unknown_mid;
  for (int j = 0; j < space_.n_unknowns(); ++j) unknown_mid.push_back(std::nan(""));
  space_.assemble(proto, unknown_mid.data(), fixed_full_.data());
  for (std::size_t i = 0; i < model_names.size(); ++i)
    if (std::isnan(fixed_full_[i]) && !scan.truth.count(std::string(model_names[i])))
      fail(scan_path, "truth." + std::string(model_names[i]) + ": missing (it is not fixed in the config)");
}

std::vector<double> ScanTruth::full_at(int pixel) const {
  std::vector<double> full = fixed_full_;
  const auto model_names = force_model_parameters(space_.model());
  for (std::size_t i = 0; i < model_names.size(); ++i) {
    auto it = scan_->truth.find(std::string(model_names[i]));
    if (it != scan_->truth.end()) full[i] = it->second[static_cast<std::size_t>(pixel)];
  }
  const ParameterLayout layout(space_.model());
  full[layout.drive_index(DriveParameter::amplitude_m)] = scan_->drive.amplitude_m;
  full[layout.drive_index(DriveParameter::frequency_hz)] = scan_->drive.frequency_hz;
  full[layout.drive_index(DriveParameter::phase_rad)] = scan_->drive.phase_rad;
  full[layout.drive_index(DriveParameter::chirp_hz_per_s)] = scan_->drive.chirp_hz_per_s;
  return full;
}

void check_scan_windows_for_probe(const Scan& scan, const ProbeModel& probe, const std::string& scan_path) {
  const WindowLimits limits = probe.limits.value_or(window_limits(probe.modal, 0.0, probe.space, kMaxWindowSamples));
  const int last = scan.pixels_x * scan.pixels_y - 1;
  // The windows differ only in t0, and what depends on it (its bound, a chirp's instantaneous
  // frequency) is monotone in t: the first and the last window hold the extremes.
  for (int px : {0, last}) {
    Window w;
    w.drive = scan.drive;
    w.sample_period_s = scan.sample_period_s;
    w.t0_s = static_cast<double>(px) * scan.samples_per_window * scan.sample_period_s;
    w.deflection_m.assign(static_cast<std::size_t>(scan.samples_per_window), 0.0);
    std::optional<std::string> problem = window_problem(w);
    if (!problem) problem = window_problem_for_probe(w, limits);
    if (problem)
      fail(scan_path, "pixel (" + std::to_string(px % scan.pixels_x) + ", " + std::to_string(px / scan.pixels_x) +
                          "): " + *problem + "; tipforced and tipforce invert reject such a window for probe " +
                          probe.name);
  }
}

LeadIn lead_in(const Scan& scan, double mode1_decay_s) {
  LeadIn l;
  l.duration_s = 6 * mode1_decay_s;
  const double longest_s = kMaxLeadPeriods / scan.drive.frequency_hz;
  if (l.duration_s > longest_s) {
    l.duration_s = longest_s;
    l.capped = true;
  }
  // The scan's own sampling where the run-in needs at most kMaxLeadSamples of it (the data are
  // then as they always were); else coarser, which the adaptive reference does not mind: its
  // steps follow its tolerance (at most half a sample period), and only the end state is kept.
  l.sample_period_s = scan.sample_period_s;
  if (l.duration_s / l.sample_period_s > kMaxLeadSamples) l.sample_period_s = l.duration_s / kMaxLeadSamples;
  l.samples = std::max<std::int64_t>(1, static_cast<std::int64_t>(l.duration_s / l.sample_period_s));
  return l;
}

InitialState scan_initial_state(const Scan& scan, int px) {
  if (px == 0) return scan.start == "rest" ? InitialState::rest : InitialState::unknown;
  if (px % scan.pixels_x == 0 && scan.line_start == "unknown") return InitialState::unknown;
  return InitialState::continued;
}

ModalState scan_start_state(const Scan& scan, const ProbeModel& probe, const std::vector<double>& full) {
  const int M = probe.modal.n_modes();
  if (scan.start != "steady") return ModalState::rest(M);
  const double tau = 2 * probe.modal.modes()[0].quality_factor / probe.modal.modes()[0].omega_rad_per_s;
  const LeadIn lead = lead_in(scan, tau);
  if (lead.capped) {
    char note[320];
    std::snprintf(note, sizeof note,
                  "tipforce simulate: start = \"steady\": mode 1 decays in %.3g s (Q %.3g); the run-in stops after "
                  "%.0f drive periods (%.3g s), so the first windows still carry %.2g of the start's transient\n",
                  tau, probe.modal.modes()[0].quality_factor, kMaxLeadPeriods, lead.duration_s,
                  std::exp(-lead.duration_s / tau));
    std::cerr << note;
  }
  Window w;
  w.drive = scan.drive;
  w.sample_period_s = lead.sample_period_s;
  w.t0_s = -lead.samples * lead.sample_period_s;
  w.deflection_m.assign(static_cast<std::size_t>(lead.samples), 0.0);
  const ParameterLayout layout(probe.space.model());
  std::vector<double> lead_full = full;
  // A chirp's steady start is the sine's at the chirp's frequency at t = 0, where the chirp
  // begins (base position and velocity continue there). Run in under the chirp itself, the lead-in
  // drove at f + 2 g t back to t = -6 tau: at 4e9 Hz/s over 7.5 ms, 60 MHz, a state of junk.
  if (w.drive.kind == DriveKind::chirp) {
    w.drive.kind = DriveKind::sine;
    w.drive.chirp_hz_per_s = 0;
    lead_full[layout.drive_index(DriveParameter::chirp_hz_per_s)] = 0;
  }
  const FullParams p(layout, lead_full);
  const ModalState linear = linear_steady_state(probe.modal, p.drive(DriveParameter::amplitude_m),
                                                p.drive(DriveParameter::frequency_hz),
                                                p.drive(DriveParameter::phase_rad), w.t0_s);
  return reference_simulate(probe.modal, probe.space.model(), w, lead_full, linear).end_state;
}

}  // namespace tipforce::cli
