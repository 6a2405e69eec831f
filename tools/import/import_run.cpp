#include "import_run.hpp"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <memory>
#include <vector>

#include "import_error.hpp"
#include "tipforce/deflection_window_t.hpp"
#include "tipforce/event_log.hpp"
#include "tipforce/lcm_convert.hpp"
#include "tipforce/scan_geometry_t.hpp"

namespace tipforce::import {
namespace {

int resolve_column(const RecordSource& src, const std::string& column, const std::string& option) {
  if (column.empty()) return 0;
  int index = src.column_named(column);
  if (index < 0) {
    try {
      std::size_t used = 0;
      index = std::stoi(column, &used);
      if (used != column.size()) index = -1;
    } catch (const std::exception&) {
      index = -1;
    }
  }
  if (index < 0 || index >= src.columns())
    throw ImportError(src.describe() + ": " + option + " " + column + ": no such column (the record has " +
                      std::to_string(src.columns()) + ", numbered from 0)");
  return index;
}

void check_calibration(const Calibration& c, const std::string& prefix) {
  if (!std::isfinite(c.sensitivity_m_per_v) || c.sensitivity_m_per_v == 0)
    throw ImportError(prefix + "sensitivity-m-per-v must be a finite, non-zero number of metres per volt");
  if (!std::isfinite(c.offset_v)) throw ImportError(prefix + "offset-v must be finite");
  if (!std::isfinite(c.volts_per_count) || c.volts_per_count == 0)
    throw ImportError("--volts-per-count must be a finite, non-zero number");
}

struct Channel {
  std::unique_ptr<RecordSource> source;
  int column = 0;
  Calibration calibration;
};

// Reads one window of a channel in metres; every sample must be finite (and fit a float, the
// message's type), else the error names the file, the sample and the pixel.
void read_metres(Channel& ch, std::int64_t first_row, std::int64_t n, const WindowSlice& where,
                 const char* what, std::vector<double>& raw, std::vector<float>& out) {
  raw.resize(static_cast<std::size_t>(n));
  ch.source->read(ch.column, first_row, n, raw.data());
  out.resize(static_cast<std::size_t>(n));
  const Calibration& c = ch.calibration;
  for (std::int64_t i = 0; i < n; ++i) {
    const double v = raw[static_cast<std::size_t>(i)];
    const double m = (v * c.volts_per_count - c.offset_v) * c.sensitivity_m_per_v;
    const float f = static_cast<float>(m);
    if (!std::isfinite(v) || !std::isfinite(f))
      throw ImportError(ch.source->describe() + ": " + ch.source->locate(first_row + i) + " (" + what + " of pixel " +
                        std::to_string(where.pixel_x) + "," + std::to_string(where.pixel_y) + ") is " +
                        (std::isnan(v)      ? "NaN; a record with gaps must be cut or repaired before import"
                         : std::isfinite(v) ? "too large for a float once calibrated (check --volts-per-count, "
                                              "--offset-v and the sensitivity)"
                                            : "infinite; a record with gaps must be cut or repaired before import"));
    out[static_cast<std::size_t>(i)] = f;
  }
}

// The window as its readers see it, checked against the probe's limits.
void refuse_if_the_probe_would(const ImportOptions& o, const deflection_window_t& w) {
  Window chk;
  chk.sample_period_s = o.sample_period_s;
  chk.t0_s = w.t0_s;
  chk.drive = o.drive;
  chk.deflection_m.assign(w.deflection_m.begin(), w.deflection_m.end());
  if (o.drive.kind == DriveKind::sampled) chk.drive.base_m.assign(w.base_m.begin(), w.base_m.end());
  if (auto problem = window_problem_for_probe(chk, *o.limits))
    throw ImportError("pixel (" + std::to_string(w.pixel_x) + ", " + std::to_string(w.pixel_y) + "): " + *problem +
                      "; tipforced and tipforce invert reject such a window for probe " + o.probe + " (--config)");
}

}  // namespace

ImportReport run_import(const ImportOptions& o, std::ostream& log_out) {
  check_geometry(o.geometry);
  if (!(o.sample_period_s > 0) || !std::isfinite(o.sample_period_s))
    throw ImportError("--sample-period-s must be a positive number of seconds");
  if (auto why = lcmio::probe_name_problem(o.probe)) throw ImportError("--probe: " + *why);
  if (!(o.scan_size_x_m >= 0 && o.scan_size_y_m >= 0 && std::isfinite(o.scan_size_x_m) && std::isfinite(o.scan_size_y_m)))
    throw ImportError("--scan-size-m must be finite and positive");
  if (o.out.empty()) throw ImportError("no output log given (--out)");
  check_calibration(o.deflection.calibration, "--");
  const bool sampled = o.drive.kind == DriveKind::sampled;
  if (sampled != o.base.has_value())
    throw ImportError(sampled ? "--drive sampled needs the base channel (--base-column, --base-dataset or --base)"
                              : "a base channel was given: use --drive sampled with it");
  if (sampled) check_calibration(o.base->calibration, "--base-");

  Channel defl{open_record(o.deflection.record), 0, o.deflection.calibration};
  defl.column = resolve_column(*defl.source, o.deflection.column, "--column");
  std::optional<Channel> base;
  if (o.base) {
    base.emplace();
    base->source = open_record(o.base->record);
    base->column = resolve_column(*base->source, o.base->column, "--base-column");
    base->calibration = o.base->calibration;
    if (base->source->rows() != defl.source->rows())
      throw ImportError(base->source->describe() + ": the base channel has " + std::to_string(base->source->rows()) +
                        " samples, the deflection " + defl.source->describe() + " " +
                        std::to_string(defl.source->rows()) + ": the two must be sampled together");
  }

  ImportReport rep;
  rep.source = defl.source->describe();
  rep.record_rows = defl.source->rows();
  rep.rows_used = record_rows_needed(o.geometry);
  rep.samples_per_window = window_length(o.geometry);
  const ScanGeometry& g = o.geometry;
  if (rep.record_rows < rep.rows_used) {
    // How far the record gets, in whole lines, to help tell a short capture from a wrong geometry.
    const std::int64_t stride = (rep.rows_used - g.skip_samples + g.line_gap_samples) / g.lines;
    const std::int64_t after_skip = std::max<std::int64_t>(0, rep.record_rows - g.skip_samples);
    const std::int64_t whole = after_skip / stride, rest = after_skip % stride;
    throw ImportError(rep.source + ": record too short for the geometry: " + std::to_string(g.lines) + " lines of " +
                      std::to_string(g.pixels_per_line) + " pixels x " + std::to_string(g.samples_per_pixel) +
                      " samples" + (g.trace_and_retrace ? " (trace and retrace)" : "") + " need " +
                      std::to_string(rep.rows_used) + " samples, the file holds " + std::to_string(rep.record_rows) +
                      " (" + std::to_string(whole) + " whole line" + (whole == 1 ? "" : "s") +
                      (rest ? " and " + std::to_string(rest) + " samples" : "") + "); nothing was imported");
  }

  // Written beside the target and renamed at the end: an error leaves no partial log.
  namespace fs = std::filesystem;
  for (const auto* in : {&o.deflection.record.path, o.base ? &o.base->record.path : nullptr})
    if (in && fs::exists(o.out) && lcmio::same_file(*in, o.out))
      throw ImportError("--out " + o.out + " is the input " + *in);
  const std::string tmp = o.out + ".partial-" + std::to_string(::getpid());
  struct RemoveOnFailure {
    std::string path;
    bool keep = false;
    ~RemoveOnFailure() {
      std::error_code ec;
      if (!keep) fs::remove(path, ec);
    }
  } cleanup{tmp};
  std::unique_ptr<lcmio::LogWriter> writer;
  try {
    writer = std::make_unique<lcmio::LogWriter>(tmp, /*append=*/false);
  } catch (const lcmio::LogError& e) {
    throw ImportError(std::string("--out: ") + e.what());
  }
  std::vector<std::uint8_t> buf;
  auto write = [&](const std::string& channel, std::int64_t utime, const auto& msg) {
    buf.resize(static_cast<std::size_t>(msg.getEncodedSize()));
    msg.encode(buf.data(), 0, static_cast<int>(buf.size()));
    if (!writer->write(channel, utime, buf.data(), buf.size())) throw ImportError(o.out + ": " + writer->error());
  };

  scan_geometry_t scan;
  scan.utime = o.start_utime;
  scan.probe = o.probe;
  scan.pixels_x = g.pixels_per_line;
  scan.pixels_y = g.lines;
  scan.size_x_m = o.scan_size_x_m;
  scan.size_y_m = o.scan_size_y_m;
  scan.direction = g.keep_retrace ? scan_geometry_t::DIRECTION_RETRACE : scan_geometry_t::DIRECTION_TRACE;
  scan.source = rep.source;
  write(o.scan_channel, scan.utime, scan);

  deflection_window_t w;
  w.probe = o.probe;
  w.sample_period_s = o.sample_period_s;
  w.drive_kind = sampled ? deflection_window_t::DRIVE_SAMPLED
                 : o.drive.kind == DriveKind::chirp ? deflection_window_t::DRIVE_CHIRP
                                                    : deflection_window_t::DRIVE_SINE;
  w.drive_amplitude_m = o.drive.amplitude_m;
  w.drive_frequency_hz = o.drive.frequency_hz;
  w.drive_phase_rad = o.drive.phase_rad;
  w.drive_chirp_hz_per_s = o.drive.chirp_hz_per_s;
  const std::int64_t n = rep.samples_per_window;
  w.n_samples = static_cast<std::int32_t>(n);
  std::vector<double> raw;
  for (std::int64_t i = 0; i < window_count(g); ++i) {
    const WindowSlice s = window_slice(g, i);
    w.seq = i;
    w.pixel_x = s.pixel_x;
    w.pixel_y = s.pixel_y;
    // SPEC 2: CONTINUED only where this window starts exactly where the previous one ended.
    w.initial_state = s.continued ? deflection_window_t::INITIAL_CONTINUED : deflection_window_t::INITIAL_UNKNOWN;
    // The drive's clock and the record's: t = 0 at the record's first sample.
    w.t0_s = static_cast<double>(s.first_row) * o.sample_period_s;
    w.utime = o.start_utime + static_cast<std::int64_t>(std::llround(w.t0_s * 1e6));
    read_metres(defl, s.first_row, n, s, "deflection", raw, w.deflection_m);
    if (base) {
      read_metres(*base, s.first_row, n, s, "base", raw, w.base_m);
      w.n_base_samples = w.n_samples;
    } else {
      w.base_m.clear();
      w.n_base_samples = 0;
    }
    if (o.limits) refuse_if_the_probe_would(o, w);
    write(o.window_channel, w.utime, w);
    ++rep.windows;
  }
  if (!writer->close()) throw ImportError(o.out + ": " + writer->error());
  std::error_code ec;
  fs::rename(tmp, o.out, ec);
  if (ec) throw ImportError("cannot move " + tmp + " to " + o.out + ": " + ec.message());
  cleanup.keep = true;

  log_out << "imported " << rep.windows << " windows of " << n << " samples (" << g.pixels_per_line << " x " << g.lines
          << " pixels, " << (g.keep_retrace ? "retrace" : "trace") << ") from " << rep.source << " to " << o.out
          << "\n";
  if (rep.record_rows > rep.rows_used)
    log_out << "note: the record holds " << rep.record_rows - rep.rows_used
            << " samples after the scan's last line; they were not imported (check --lines and --samples-per-pixel)\n";
  if (o.scan_size_x_m == 0)
    log_out << "note: no --scan-size-m: maps of this scan will have pixel axes, no physical scale\n";
  return rep;
}

}  // namespace tipforce::import
