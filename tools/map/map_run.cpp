#include "map_run.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <optional>
#include <set>
#include <system_error>

#include "estimate_log.hpp"
#include "estimate_table.hpp"
#include "gsf_writer.hpp"
#include "figure.hpp"
#include "map_error.hpp"

namespace tipforce::map {
namespace {
namespace fs = std::filesystem;

std::string coords(const std::vector<std::pair<int, int>>& px, std::size_t first_n = 8) {
  std::string s;
  for (std::size_t i = 0; i < std::min(px.size(), first_n); ++i) {
    if (i) s += ' ';
    s += '(';
    s += std::to_string(px[i].first);
    s += ',';
    s += std::to_string(px[i].second);
    s += ')';
  }
  if (px.size() > first_n) s += " ...";
  return s;
}

std::vector<tipforce::force_estimate_t> select_probe(std::vector<tipforce::force_estimate_t> all, const MapOptions& opt,
                                                     std::string& probe) {
  std::map<std::string, std::size_t> probes;
  for (const auto& e : all) ++probes[e.probe];
  auto listing = [&] {
    std::string s;
    for (const auto& [name, n] : probes) s += (s.empty() ? "" : ", ") + ("\"" + name + "\": " + std::to_string(n));
    return s;
  };
  if (!opt.probe.empty()) {
    if (!probes.count(opt.probe))
      throw MapInputError(opt.in + " has no estimates of probe \"" + opt.probe + "\" (probes: " + listing() + ")");
    probe = opt.probe;
    std::erase_if(all, [&](const auto& e) { return e.probe != opt.probe; });
    return all;
  }
  if (probes.size() > 1)
    throw MapInputError(opt.in + " holds estimates of " + std::to_string(probes.size()) + " probes (" + listing() +
                   "); choose one with --probe");
  probe = probes.begin()->first;
  return all;
}

void prepare_out_dir(const std::string& dir) {
  std::error_code ec;
  if (fs::exists(dir, ec) && !fs::is_directory(dir, ec)) throw MapError("output " + dir + " exists and is not a directory");
  fs::create_directories(dir, ec);
  if (ec) throw MapError("cannot create output directory " + dir + ": " + ec.message());
}

// The scan_geometry_t messages of --scan-log, read once and only when needed (it may be a whole
// windows log).
// Its damage is said in the notes: the geometry sought may have been in a stretch skipped.
class ScanLog {
 public:
  ScanLog(const MapOptions& opt, std::vector<std::string>& notes) : opt_(opt), notes_(notes) {}
  const std::vector<tipforce::scan_geometry_t>& scans() {
    if (!scans_) {
      LogContents log = read_estimate_log(opt_.scan_log, "", "", opt_.scan_channel);
      if (log.damaged_stretches > 0)
        notes_.push_back(opt_.scan_log + " (--scan-log): " + std::to_string(log.damaged_stretches) + " damaged stretch" +
                         (log.damaged_stretches == 1 ? "" : "es") + " skipped" +
                         (log.damage.empty() ? "" : " (" + log.damage.front() + (log.damage.size() > 1 ? ", ..." : "") + ")"));
      scans_ = std::move(log.scans);
    }
    return *scans_;
  }

 private:
  const MapOptions& opt_;
  std::vector<std::string>& notes_;
  std::optional<std::vector<tipforce::scan_geometry_t>> scans_;
};

// The estimates logs, as a message names them: merged, a scan_geometry_t is in any of them.
std::string inputs_name(const MapOptions& opt) {
  return opt.more_in.empty() ? opt.in : "the " + std::to_string(1 + opt.more_in.size()) + " logs (" + opt.in + ", ...)";
}

// Logs of different scans of one probe merged (a stale log caught by a wildcard, or one log over
// several scans): the map's grid and axes are the last scan's, and the note says so.
void note_different_scans(const std::vector<tipforce::scan_geometry_t>& scans, const std::string& probe,
                          std::vector<std::string>& notes) {
  std::vector<std::string> distinct;
  for (const auto& g : scans) {
    if (g.probe != probe) continue;
    char d[160];
    std::snprintf(d, sizeof d, "%d x %d pixels, %.3g x %.3g m", g.pixels_x, g.pixels_y, g.size_x_m, g.size_y_m);
    const std::string what = std::string(d) + (g.source.empty() ? "" : " from '" + g.source + "'");
    if (std::find(distinct.begin(), distinct.end(), what) == distinct.end()) distinct.push_back(what);
  }
  if (distinct.size() < 2) return;
  std::string list;
  for (const auto& d : distinct) list += (list.empty() ? "" : "; ") + d;
  notes.push_back("the estimates come from " + std::to_string(distinct.size()) + " different scans of probe " + probe +
                  " (" + list + "): the map's size and axes are the last one's, and pixels of the others are drawn " +
                  "on its grid; map each scan's estimates apart");
}

// The scan size by the first source that has one (MapOptions says which order).
void resolve_scan_size(const MapOptions& opt, const std::vector<tipforce::scan_geometry_t>& in_log, ScanLog& scan_log,
                       MapReport& rep, int width, int height) {
  auto from_message = [&](const std::vector<tipforce::scan_geometry_t>& scans, const std::string& where) {
    for (auto it = scans.rbegin(); it != scans.rend(); ++it)
      if (it->probe == rep.probe && it->size_x_m > 0 && it->size_y_m > 0 && std::isfinite(it->size_x_m + it->size_y_m)) {
        rep.scan = {it->size_x_m, it->size_y_m};
        rep.scan_source = "scan_geometry_t in " + where;
        if (it->pixels_x != width || it->pixels_y != height)
          rep.notes.push_back(where + " describes a scan of " + std::to_string(it->pixels_x) + " x " +
                              std::to_string(it->pixels_y) + " pixels, the map has " + std::to_string(width) +
                              " x " + std::to_string(height) + ": axes from its size per pixel");
        rep.scan.x_m *= static_cast<double>(width) / std::max(1, it->pixels_x);
        rep.scan.y_m *= static_cast<double>(height) / std::max(1, it->pixels_y);
        return true;
      }
    return false;
  };
  if (opt.scan_size_x_m > 0) {
    rep.scan = {opt.scan_size_x_m, opt.scan_size_y_m > 0 ? opt.scan_size_y_m : opt.scan_size_x_m * height / width};
    rep.scan_source = "--scan-size-m";
  } else if (opt.pixel_size_m > 0) {
    rep.scan = {opt.pixel_size_m * width, opt.pixel_size_m * height};
    rep.scan_source = "--pixel-size-m";
  } else if (from_message(in_log, inputs_name(opt))) {
  } else if (!opt.scan_log.empty()) {
    if (!from_message(scan_log.scans(), opt.scan_log))
      rep.notes.push_back(opt.scan_log + " holds no scan_geometry_t of probe " + rep.probe + " on " + opt.scan_channel);
  }
}

// The scan's size in pixels, from the last scan_geometry_t of the probe in the estimates log,
// else in --scan-log: what the map must cover, so that a log cut short shows its lost pixels.
struct ScanPixels {
  int x = 0, y = 0;
  std::string source;
};
ScanPixels scan_pixels(const MapOptions& opt, const std::vector<tipforce::scan_geometry_t>& in_log, ScanLog& scan_log,
                       const std::string& probe, std::vector<std::string>& notes) {
  auto from = [&](const std::vector<tipforce::scan_geometry_t>& scans, const std::string& where) -> ScanPixels {
    for (auto it = scans.rbegin(); it != scans.rend(); ++it) {
      if (it->probe != probe) continue;
      // A damaged or forged message is no reason to allocate gigapixels: such a one is not used.
      if (it->pixels_x < 1 || it->pixels_y < 1 ||
          static_cast<long long>(it->pixels_x) * it->pixels_y > 64LL * 1024 * 1024) {
        notes.push_back("scan_geometry_t in " + where + " gives " + std::to_string(it->pixels_x) + " x " +
                        std::to_string(it->pixels_y) + " pixels: not used for the map's size");
        return {};
      }
      return {it->pixels_x, it->pixels_y, "scan_geometry_t in " + where};
    }
    return {};
  };
  ScanPixels p = from(in_log, inputs_name(opt));
  if (p.x == 0 && !opt.scan_log.empty())
    p = from(scan_log.scans(), opt.scan_log);
  return p;
}

void print_wrapped(std::ostream& out, const std::vector<std::string>& items, const std::string& indent) {
  std::string line = indent;
  for (const auto& it : items) {
    if (line.size() > indent.size() && line.size() + it.size() + 1 > 100) {
      out << line << '\n';
      line = indent;
    }
    line += (line.size() > indent.size() ? " " : "") + it;
  }
  if (line.size() > indent.size()) out << line << '\n';
}
}  // namespace

MapReport run_map(const MapOptions& opt, std::ostream& out) {
  if (opt.in.empty()) throw MapInputError("no input log given (--in)");
  if (opt.out.empty()) throw MapInputError("no output directory given (--out)");
  auto metres = [](double v) {
    char b[32];
    std::snprintf(b, sizeof b, "%g", v);
    return std::string(b);
  };
  if (!(opt.pixel_size_m >= 0) || !std::isfinite(opt.pixel_size_m))
    throw MapInputError("--pixel-size-m must be a positive number of metres, got " + metres(opt.pixel_size_m));
  if (!(opt.scan_size_x_m >= 0 && opt.scan_size_y_m >= 0 && std::isfinite(opt.scan_size_x_m + opt.scan_size_y_m)))
    throw MapInputError("--scan-size-m must be positive numbers of metres, got " + metres(opt.scan_size_x_m) +
                        (opt.scan_size_y_m != 0 ? "," + metres(opt.scan_size_y_m) : std::string()));

  std::vector<std::string> inputs{opt.in};
  inputs.insert(inputs.end(), opt.more_in.begin(), opt.more_in.end());
  std::vector<std::string> merge_notes;
  LogContents log = read_estimate_logs(inputs, opt.channel, opt.stats_channel, opt.scan_channel, merge_notes);
  MapReport rep;
  rep.notes = merge_notes;
  rep.undecodable_estimates = log.undecodable_estimates;
  rep.undecodable_stats = log.undecodable_stats;
  rep.damaged_stretches = log.damaged_stretches;
  rep.damage = log.damage;
  rep.stats_messages = log.stats.size();
  if (log.estimates.empty()) {
    std::string channels;
    for (const auto& [name, n] : log.other_channels) channels += (channels.empty() ? "" : ", ") + name + " (" + std::to_string(n) + ")";
    const std::string what =
        (opt.more_in.empty() ? opt.in + " holds no"
                             : "none of the " + std::to_string(inputs.size()) + " logs (" + opt.in + ", ...) holds a") +
        " decodable force_estimate_t on channel " + opt.channel + " (" + std::to_string(log.events) +
        " events; undecodable on " + opt.channel + ": " + std::to_string(log.undecodable_estimates) +
        (channels.empty() ? "" : "; other channels: " + channels) + ")";
    // As tipforce invert with a log without windows: where part of the log was damaged the
    // estimates may have been there (exit 3); an intact log without any is the wrong file (exit 2).
    if (log.damaged_stretches > 0) {
      std::vector<std::string> damage;
      for (const auto& line : log.damage) damage.push_back(opt.more_in.empty() ? opt.in + ": " + line : line);
      throw MapDamagedError(what + ", and " + std::to_string(log.damaged_stretches) + " damaged stretch" +
                                (log.damaged_stretches == 1 ? " was" : "es were") + " skipped",
                            std::move(damage));
    }
    throw MapInputError(what);
  }
  const auto estimates = select_probe(std::move(log.estimates), opt, rep.probe);
  rep.estimates = estimates.size();
  for (const auto& e : estimates) ++rep.per_status[e.status];

  // Read before anything is written: a bad truth row is refused with nothing left behind.
  std::optional<TruthTable> truth;
  if (!opt.truth.empty()) truth = read_truth_csv(opt.truth);

  note_different_scans(log.scans, rep.probe, rep.notes);
  ScanLog scan_log(opt, rep.notes);
  const ScanPixels scan_px = scan_pixels(opt, log.scans, scan_log, rep.probe, rep.notes);
  // Its refusals (no estimate at a pixel index >= 0, pixel indices beyond 64 Mpixel) are about
  // what the log holds: bad input, named by the log.
  const MapSet ms = [&] {
    try {
      return build_maps(estimates, scan_px.x, scan_px.y);
    } catch (const MapError& e) {
      throw MapInputError(inputs_name(opt) + ": " + e.what());
    }
  }();
  rep.width = ms.width;
  rep.height = ms.height;
  rep.missing = ms.missing;
  rep.rejected = ms.rejected;
  if (ms.negative_pixels) rep.notes.push_back(std::to_string(ms.negative_pixels) + " estimates with a negative pixel index were ignored");
  if (ms.duplicates)
    rep.notes.push_back(std::to_string(ms.duplicates) + " estimates were for a pixel already seen; the later one is mapped");
  if (ms.param_names.empty()) rep.notes.push_back("no estimate names any parameter: only derived quantities are mapped");

  // It may read --scan-log, whose errors are bad input: before the output directory is made.
  resolve_scan_size(opt, log.scans, scan_log, rep, ms.width, ms.height);
  prepare_out_dir(opt.out);
  auto file = [&](const std::string& name) { return (fs::path(opt.out) / name).string(); };
  std::set<std::string> models;
  for (const auto& e : estimates)
    if (!e.model.empty()) models.insert(e.model);  // a rejection names no model
  if (models.empty()) models.insert("none (every estimate rejected)");
  std::string model_list;
  for (const auto& m : models) model_list += (model_list.empty() ? "" : ", ") + m;
  const std::string subtitle = "probe " + rep.probe + ", model " + model_list;

  // Spring, Hertz and DMT forces are conservative: what they dissipate is zero by construction,
  // and a map of the estimates' values would show only the integrator's error as if it were data.
  rep.dissipation_mapped = std::any_of(models.begin(), models.end(), [](const std::string& m) {
    return m == "kelvin_voigt" || m == "dmt_viscous" || m.empty();
  });
  if (!rep.dissipation_mapped) {
    double largest = 0;
    for (const auto& e : estimates)
      if (std::isfinite(e.dissipated_energy_j)) largest = std::max(largest, std::abs(e.dissipated_energy_j));
    char b[64];
    std::snprintf(b, sizeof b, "%.2g", largest);
    rep.notes.push_back("dissipated energy not mapped: model " + model_list +
                        " does not dissipate (zero by construction; the estimates' values, up to " + b +
                        " J, are the integrator's error)");
  }

  GsfMeta geometry;
  if (rep.scan.known()) {
    geometry.x_real = rep.scan.x_m;
    geometry.y_real = rep.scan.y_m;
  } else {
    // Gwyddion needs a size: one unit per pixel, and the file says the scan size is unknown.
    geometry.x_real = ms.width;
    geometry.y_real = ms.height;
    geometry.xy_units = "";
    geometry.extra.emplace_back("tipforce_scan_size", "unknown (XReal, YReal count pixels)");
  }
  for (const auto& m : ms.maps) {
    if (m.quantity.key == "dissipated_energy_j" && !rep.dissipation_mapped) continue;
    rep.images.push_back(write_map_png(file(m.quantity.key + ".png"), m, subtitle, rep.scan));
    rep.files.push_back(m.quantity.key + ".png");
    rep.files.push_back(m.quantity.key + ".pdf");
    GsfMeta meta = geometry;
    meta.z_units = m.quantity.si_unit;
    meta.title = m.quantity.key + " (" + m.quantity.title + ")";
    if (m.quantity.display_factor != 1.0) {
      meta.title = "height = -" + m.quantity.key + " (topography: higher = nearer the cantilever)";
      meta.extra.emplace_back("tipforce_convention", "values are -h_m: height, bright = high");
    }
    write_gsf(file(m.quantity.key + ".gsf"), scaled(m.grid, m.quantity.display_factor), meta);
    rep.files.push_back(m.quantity.key + ".gsf");
  }
  rep.images.push_back(write_status_png(file("status.png"), ms.status, subtitle, rep.scan));
  rep.files.push_back("status.png");
  rep.files.push_back("status.pdf");
  {
    GsfMeta meta = geometry;
    meta.title = "status (0 ok, 1 not converged, 2 rejected, NaN no estimate)";
    write_gsf(file("status.gsf"), ms.status, meta);
    rep.files.push_back("status.gsf");
  }
  write_estimate_table(file("estimates.csv"), estimates, ms.param_names);
  rep.files.push_back("estimates.csv");

  rep.latency = summarize_latency(estimates);
  if (rep.latency) {
    write_latency_histogram(file("latency_histogram.png"), estimates, *rep.latency);
    write_latency_over_time(file("latency_over_time.png"), estimates, log.stats);
    for (const char* f : {"latency_histogram.png", "latency_histogram.pdf", "latency_over_time.png", "latency_over_time.pdf"})
      rep.files.push_back(f);
    if (rep.latency->negative)
      rep.notes.push_back(std::to_string(rep.latency->negative) + " estimates were published before they were received (clock steps?)");
  } else {
    rep.notes.push_back("no estimate carries receive/publish times (both 0): latency plots skipped");
  }

  std::vector<std::string> only_truth;
  if (truth) {
    rep.accuracy = compare_with_truth(*truth, ms, opt.out, &only_truth);
    for (const auto& a : rep.accuracy) {
      rep.files.push_back(fs::path(a.comparison_png).filename().string());
      rep.files.push_back(fs::path(pdf_path_for(a.comparison_png)).filename().string());
    }
    if (rep.accuracy.empty()) rep.notes.push_back("no parameter is both in " + opt.truth + " and estimated");
    if (truth->width != ms.width || truth->height != ms.height)
      rep.notes.push_back("truth covers " + std::to_string(truth->width) + " x " + std::to_string(truth->height) +
                          " pixels, the map " + std::to_string(ms.width) + " x " + std::to_string(ms.height));
  }

  // --- summary ----------------------------------------------------------------------------
  auto count = [&](int s) { return rep.per_status.count(s) ? rep.per_status.at(s) : std::size_t{0}; };
  std::size_t other = rep.estimates - count(0) - count(1) - count(2);
  out << "tipforce map: " << opt.in << "  (probe \"" << rep.probe << "\", model " << model_list << ")\n";
  out << "  estimates: " << rep.estimates << "  (ok " << count(0) << ", not converged " << count(1) << ", rejected "
      << count(2);
  if (other) out << ", unknown status " << other;
  out << "); stats messages: " << rep.stats_messages << "\n";
  out << "  map: " << ms.width << " x " << ms.height << " pixels (pixel_x 0.." << ms.width - 1 << ", pixel_y 0.."
      << ms.height - 1 << (scan_px.x > 0 ? "; the scan's, from " + scan_px.source : std::string()) << "), ";
  if (rep.scan.known()) {
    char size[96];
    std::snprintf(size, sizeof size, "%g m x %g m", rep.scan.x_m, rep.scan.y_m);
    out << "scan " << size << " (" << rep.scan_source << ")\n";
  } else {
    out << "scan size unknown: pixel axes (give tipforce import --scan-size-m, or --scan-size-m / --scan-log here)\n";
  }
  if (ms.missing.empty())
    out << "  missing pixels: none\n";
  else
    out << "  missing pixels (no estimate, grey): " << ms.missing.size() << ": " << coords(ms.missing) << "\n";
  if (!ms.rejected.empty())
    out << "  rejected pixels (no parameters, grey): " << ms.rejected.size() << ": " << coords(ms.rejected) << "\n";
  out << "  undecodable messages: " << rep.undecodable_estimates << " on " << opt.channel << ", " << rep.undecodable_stats
      << " on " << opt.stats_channel << "\n";
  if (!log.damage.empty()) {
    out << "  damaged log stretches skipped: " << log.damage.size() << "\n";
    for (const auto& line : log.damage) out << "    " << line << "\n";
  }
  if (!log.other_channels.empty()) {
    out << "  other channels skipped:";
    for (const auto& [name, n] : log.other_channels) out << " " << name << " (" << n << ")";
    out << "\n";
  }
  if (rep.latency)
    out << "  latency receive->publish: n " << rep.latency->n << ", p50 " << format_us(rep.latency->p50_us)
        << " us, p90 " << format_us(rep.latency->p90_us) << " us, p99 " << format_us(rep.latency->p99_us)
        << " us, max " << format_us(rep.latency->max_us) << " us\n";
  for (const auto& n : rep.notes) out << "  note: " << n << "\n";
  if (!opt.truth.empty()) {
    out << "accuracy against " << opt.truth << ":\n";
    char line[256];
    std::snprintf(line, sizeof line, "  %-20s %8s %16s %14s %16s %18s %16s\n", "parameter", "pixels", "median rel err",
                  "p90 rel err", "within 2 sigma", "median sigma/value", "max/median sigma");
    out << line;
    auto print = [&](const std::string& name, const TruthFigures& f) {
      std::snprintf(line, sizeof line, "  %-20s %8zu %15.3g%% %13.3g%% %15.1f%% %17.3g%% %16.3g\n", name.c_str(),
                    f.compared, f.median_rel_err * 100, f.p90_rel_err * 100, f.frac_within_2sigma * 100,
                    f.median_rel_sigma * 100, f.max_over_median_sigma);
      out << line;
    };
    for (const auto& a : rep.accuracy) print(a.name, a);
    out << "  over the OK pixels only (not converged ones left out: their values and sigma are not to be trusted):\n";
    for (const auto& a : rep.accuracy) print(a.name, a.ok);
    for (const auto& p : only_truth) out << "  " << p << ": in the truth but not estimated (fixed?)\n";
  }
  out << "files written to " << opt.out << " (" << rep.files.size() << "):\n";
  print_wrapped(out, rep.files, "  ");
  return rep;
}
}  // namespace tipforce::map
