// The command line of `tipforce import`: options to ImportOptions, errors to exit status 2.
#include "import_command.hpp"

#include <cstdio>
#include <iostream>
#include <memory>

#include "import_error.hpp"
#include "import_run.hpp"
#include "tipforce/config.hpp"

namespace tipforce::cli {
namespace {

struct Opts {
  tipforce::import::ImportOptions run;
  std::string format = "auto", base_file, base_dataset, line_layout = "trace", keep = "trace", drive = "sine", config;
  std::string base_column;
  bool base_given = false;
  double base_sensitivity_m_per_v = 0, base_offset_v = 0;
  std::vector<double> scan_size_m;
};

}  // namespace

void add_import_command(CLI::App& app) {
  auto o = std::make_shared<Opts>();
  auto& r = o->run;
  auto* cmd = app.add_subcommand("import", "Cut a continuous deflection record (HDF5, .npy, raw, CSV) into an LCM log of windows");
  cmd->footer(
      "The record is one row per sample, one column per channel. Each pixel's dwell is --samples-per-pixel\n"
      "samples; its window is --window-length samples from --window-offset within it. Deflection in metres =\n"
      "(value * --volts-per-count - --offset-v) * --sensitivity-m-per-v. A window that starts where the\n"
      "previous one ended is INITIAL_CONTINUED; the first of each line, and every window that covers only part\n"
      "of its dwell, INITIAL_UNKNOWN. A scan_geometry_t on --scan-channel comes first (the scan size for\n"
      "`tipforce map`). Errors name the file and what is wrong; nothing is written then (exit 2).\n"
      "Example: tipforce import --in scan.h5 --dataset /deflection --sensitivity-m-per-v 50e-9 \\\n"
      "  --sample-period-s 2e-7 --samples-per-pixel 400 --pixels-per-line 64 --lines 64 --probe afm1 \\\n"
      "  --drive sine --drive-amplitude-m 0.6e-9 --drive-frequency-hz 25468.9 --scan-size-m 2e-6 --out scan.lcmlog");
  cmd->add_option("--in", r.deflection.record.path, "The record: .h5/.hdf5, .npy, .csv/.txt, .bin/.raw/.dat (raw)")->required();
  cmd->add_option("--format", o->format, "auto (from the name) | hdf5 | npy | raw | csv")->capture_default_str();
  cmd->add_option("--dataset", r.deflection.record.dataset, "HDF5: the deflection dataset's path (1-D, or 2-D samples x channels)");
  cmd->add_option("--dtype", r.deflection.record.raw_dtype, "raw: int16 | float32 | float64 (little-endian)");
  cmd->add_option("--raw-channels", r.deflection.record.raw_channels, "raw: channels interleaved per sample")->capture_default_str();
  cmd->add_option("--column", r.deflection.column, "The deflection's column: index from 0, or a CSV header name (default 0)");
  cmd->add_option("--volts-per-count", r.deflection.calibration.volts_per_count,
                  "Volts per stored unit (1 for values in volts; int16 counts of a +-10 V DAQ: 10/32768)")
      ->capture_default_str();
  cmd->add_option("--offset-v", r.deflection.calibration.offset_v, "Detector reading at zero deflection, V")->capture_default_str();
  cmd->add_option("--sensitivity-m-per-v", r.deflection.calibration.sensitivity_m_per_v, "Deflection sensitivity, m/V (50 nm/V: 50e-9)")
      ->required();
  cmd->add_option("--sample-period-s", r.sample_period_s, "Sample period, s")->required();
  cmd->add_option("--samples-per-pixel", r.geometry.samples_per_pixel, "Samples in one pixel's dwell")->required();
  cmd->add_option("--window-offset", r.geometry.window_offset, "First sample of the window within the dwell")->capture_default_str();
  cmd->add_option("--window-length", r.geometry.window_length, "Window length in samples (default: the rest of the dwell)");
  cmd->add_option("--pixels-per-line", r.geometry.pixels_per_line, "Pixels per line")->required();
  cmd->add_option("--lines", r.geometry.lines, "Lines")->required();
  cmd->add_option("--line-layout", o->line_layout, "trace (one pass per line) | trace-retrace (trace, then retrace)")
      ->check(CLI::IsMember({"trace", "trace-retrace"}))->capture_default_str();
  cmd->add_option("--keep", o->keep, "Which pass to import: trace | retrace")->check(CLI::IsMember({"trace", "retrace"}))
      ->capture_default_str();
  cmd->add_option("--skip-samples", r.geometry.skip_samples, "Samples before the first line")->capture_default_str();
  cmd->add_option("--line-gap-samples", r.geometry.line_gap_samples, "Samples between lines (flyback)")->capture_default_str();
  cmd->add_option("--drive", o->drive, "sine | chirp | sampled (the measured base motion as a second channel)")
      ->check(CLI::IsMember({"sine", "chirp", "sampled"}))->capture_default_str();
  cmd->add_option("--drive-amplitude-m", r.drive.amplitude_m, "Base amplitude, m");
  cmd->add_option("--drive-frequency-hz", r.drive.frequency_hz, "Drive frequency (a chirp's start), Hz");
  cmd->add_option("--drive-phase-rad", r.drive.phase_rad, "Drive phase at the record's first sample, rad");
  cmd->add_option("--drive-chirp-hz-per-s", r.drive.chirp_hz_per_s, "Chirp rate g in y = a sin(2 pi (f + g t) t), Hz/s");
  cmd->add_option("--base", o->base_file, "sampled: the file with the base channel (default: --in)");
  cmd->add_option("--base-dataset", o->base_dataset, "sampled, HDF5: the base dataset");
  cmd->add_option("--base-column", o->base_column, "sampled: the base channel's column (index or CSV name)");
  cmd->add_option("--base-sensitivity-m-per-v", o->base_sensitivity_m_per_v, "sampled: base motion per volt, m/V");
  cmd->add_option("--base-offset-v", o->base_offset_v, "sampled: base channel reading at rest, V");
  cmd->add_option("--probe", r.probe, "Probe name (as in the tipforced config)")->required();
  cmd->add_option("--scan-size-m", o->scan_size_m, "Scan size X[,Y] in metres (Y defaults to X * lines / pixels per line)")
      ->delimiter(',')->expected(1, 2);
  cmd->add_option("--start-utime", r.start_utime, "Acquisition time of the record's first sample, us since the epoch")
      ->capture_default_str();
  cmd->add_option("--config", o->config, "Check the probe against this config and take its channel names");
  cmd->add_option("--channel", r.window_channel, "Window channel")->capture_default_str();
  cmd->add_option("--scan-channel", r.scan_channel, "Channel of the scan_geometry_t")->capture_default_str();
  cmd->add_option("--out", r.out, "Output LCM log")->required();
  cmd->callback([o, cmd] {
    auto& r = o->run;
    try {
      r.deflection.record.format = tipforce::import::parse_record_format(o->format);
      r.geometry.trace_and_retrace = o->line_layout == "trace-retrace";
      r.geometry.keep_retrace = o->keep == "retrace";
      r.drive.kind = o->drive == "chirp" ? DriveKind::chirp : o->drive == "sampled" ? DriveKind::sampled : DriveKind::sine;
      if (r.drive.kind != DriveKind::sampled &&
          (cmd->count("--drive-frequency-hz") == 0 || cmd->count("--drive-amplitude-m") == 0))
        throw tipforce::import::ImportError("--drive " + o->drive + " needs --drive-frequency-hz and --drive-amplitude-m");
      if (r.drive.kind == DriveKind::sine && r.drive.chirp_hz_per_s != 0)
        throw tipforce::import::ImportError("--drive-chirp-hz-per-s is for --drive chirp");
      // The limits tipforced's config has for the same quantities: a window outside them would be
      // written, then rejected by every reader (a NaN or negative drive frequency passed).
      const auto number = [](double v) {
        char b[32];
        std::snprintf(b, sizeof b, "%g", v);
        return std::string(b);
      };
      const auto in_range = [&](const char* option, const ValueRange& range, double value) {
        if (!range.holds(value))
          throw tipforce::import::ImportError(std::string(option) + " must be " + range.what + ", got " + number(value));
      };
      in_range("--sample-period-s", sample_period_range(), r.sample_period_s);
      in_range("--drive-amplitude-m", parameter_value_range("drive_amplitude_m"), r.drive.amplitude_m);
      in_range("--drive-frequency-hz", parameter_value_range("drive_frequency_hz"), r.drive.frequency_hz);
      if (r.drive.kind != DriveKind::sampled && !(r.drive.frequency_hz > 0))
        throw tipforce::import::ImportError("--drive-frequency-hz must be positive for --drive " + o->drive + ", got " +
                                            number(r.drive.frequency_hz));
      in_range("--drive-phase-rad", parameter_value_range("drive_phase_rad"), r.drive.phase_rad);
      in_range("--drive-chirp-hz-per-s", parameter_value_range("drive_chirp_hz_per_s"), r.drive.chirp_hz_per_s);
      // 0 stands for "the rest of the dwell" only when the option is left out.
      if (cmd->count("--window-length") > 0 && r.geometry.window_length < 1)
        throw tipforce::import::ImportError("--window-length must be " +
                                            tipforce::import::window_length_range() + ", got " +
                                            std::to_string(r.geometry.window_length) +
                                            " (leave it out for the rest of the dwell)");
      const bool base_given = !o->base_file.empty() || !o->base_dataset.empty() || !o->base_column.empty();
      if (base_given) {
        tipforce::import::ChannelSpec b;
        b.record = r.deflection.record;
        if (!o->base_file.empty()) b.record.path = o->base_file;
        if (!o->base_dataset.empty()) b.record.dataset = o->base_dataset;
        b.column = o->base_column;
        b.calibration.volts_per_count = r.deflection.calibration.volts_per_count;
        b.calibration.offset_v = o->base_offset_v;
        b.calibration.sensitivity_m_per_v = o->base_sensitivity_m_per_v;
        if (b.record.path == r.deflection.record.path && b.record.dataset == r.deflection.record.dataset &&
            (b.column.empty() ? std::string("0") : b.column) ==
                (r.deflection.column.empty() ? std::string("0") : r.deflection.column))
          throw tipforce::import::ImportError("the base channel is the deflection channel; give --base-column, "
                                              "--base-dataset or --base");
        r.base = b;
      }
      if (!o->scan_size_m.empty()) {
        r.scan_size_x_m = o->scan_size_m[0];
        r.scan_size_y_m = o->scan_size_m.size() > 1
                              ? o->scan_size_m[1]
                              : o->scan_size_m[0] * r.geometry.lines / std::max(1, r.geometry.pixels_per_line);
        if (!(r.scan_size_x_m > 0 && r.scan_size_y_m > 0))
          throw tipforce::import::ImportError("--scan-size-m must be positive");
      }
      if (!o->config.empty()) {
        const Config config = load_config(o->config);
        if (!config.probes.count(r.probe))
          throw tipforce::import::ImportError(o->config + ": probe." + r.probe + ": no such probe in the config");
        if (cmd->count("--channel") == 0) r.window_channel = config.daemon.window_channel;
        r.limits = config.probe_model(r.probe).limits;
      }
      // The channels as they will be written (the config may have set the windows'): an empty one,
      // or the windows and the scan's geometry on one, gives a log no reader takes the windows from
      // (every reader decodes a channel as one message type).
      if (r.window_channel.empty() || r.scan_channel.empty())
        throw tipforce::import::ImportError("--channel and --scan-channel must not be empty");
      if (r.window_channel == r.scan_channel)
        throw tipforce::import::ImportError("--channel and --scan-channel are both " + r.window_channel +
                                            "; the windows and the scan's geometry need channels of their own");
      tipforce::import::run_import(r, std::cout);
    } catch (const tipforce::import::ImportError& e) {
      std::cerr << "tipforce import: error: " << e.what() << "\n";
      throw CLI::RuntimeError(2);
    } catch (const ConfigError& e) {
      std::cerr << "tipforce import: config error: " << e.what() << "\n";
      throw CLI::RuntimeError(2);
    }
  });
}

}  // namespace tipforce::cli
