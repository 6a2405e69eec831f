#pragma once
// `tipforce import`: a continuous deflection record (HDF5, .npy, raw, CSV) cut into one
// deflection_window_t per pixel, calibrated to metres, written as an LCM log that `tipforce
// invert`, tipforced's file mode and lcm-logplayer read unchanged. A scan_geometry_t event comes
// first, carrying the scan's size for `tipforce map`.
#include <cstdint>
#include <optional>
#include <ostream>
#include <string>

#include "record_source.hpp"
#include "scan_layout.hpp"
#include "tipforce/drive.hpp"
#include "tipforce/window.hpp"

namespace tipforce::import {

// Stored value -> metres: ((value * volts_per_count) - offset_v) * sensitivity_m_per_v.
struct Calibration {
  double volts_per_count = 1.0;  // 1 for a file in volts; an int16 DAQ: its range / 32768
  double offset_v = 0.0;         // the detector's reading at zero deflection
  double sensitivity_m_per_v = 0.0;
};

struct ChannelSpec {
  RecordSpec record;
  std::string column;  // an index ("0") or a CSV header name; "" = 0
  Calibration calibration;
};

struct ImportOptions {
  ChannelSpec deflection;
  std::optional<ChannelSpec> base;  // the measured base motion: DRIVE_SAMPLED
  double sample_period_s = 0;
  ScanGeometry geometry;
  Drive drive;  // kind sine or chirp with its parameters (t = 0 at the record's first sample); sampled with `base`
  std::string probe;
  double scan_size_x_m = 0, scan_size_y_m = 0;  // 0 = unknown
  std::int64_t start_utime = 0;                 // acquisition time of the record's first sample
  std::string out;
  // The probe's limits from --config: a window its readers would reject is refused, naming the
  // pixel and the reason (without --config the probe is unknown, and only the value ranges hold).
  std::optional<WindowLimits> limits;
  std::string window_channel = "TIPFORCE_WINDOW";
  std::string scan_channel = "TIPFORCE_SCAN";
};

struct ImportReport {
  std::int64_t windows = 0;
  std::int64_t samples_per_window = 0;
  std::int64_t record_rows = 0;     // samples per channel in the file
  std::int64_t rows_used = 0;       // what the geometry covers
  std::string source;               // the record's description
};

// Throws ImportError naming the file and what is wrong. The log is written to a temporary file
// beside `out` and renamed at the end, so a failure never leaves a partial log behind.
ImportReport run_import(const ImportOptions& options, std::ostream& out);

}  // namespace tipforce::import
