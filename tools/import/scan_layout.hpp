#pragma once
// Where each pixel's window lies in a continuous record: the raster's geometry (pixels per line,
// lines, samples per pixel dwell, the part of the dwell that is the window, trace and retrace,
// samples skipped at the start and between lines) turned into record rows, pixel coordinates and
// whether a window continues the one before it. Pure arithmetic, no I/O.
#include <cstdint>
#include <string>

namespace tipforce::import {

struct ScanGeometry {
  std::int64_t samples_per_pixel = 0;  // one pixel's dwell
  std::int64_t window_offset = 0;      // the window's first sample within the dwell
  std::int64_t window_length = 0;      // its length; 0 = the rest of the dwell
  int pixels_per_line = 0;
  int lines = 0;
  bool trace_and_retrace = false;      // each line is recorded as a trace, then a retrace pass
  bool keep_retrace = false;           // import the retrace passes (else the trace passes)
  std::int64_t skip_samples = 0;       // before the first line
  std::int64_t line_gap_samples = 0;   // after each line (flyback, settling), not after the last
};

// Throws ImportError naming the option (--samples-per-pixel, ...) that is out of range.
void check_geometry(const ScanGeometry& g);
// The window lengths tipforce inverts, in words for messages: "8 to 1000000 samples".
std::string window_length_range();

std::int64_t window_length(const ScanGeometry& g);
// Record rows the geometry describes: from row 0 to the end of the last line's last pass.
std::int64_t record_rows_needed(const ScanGeometry& g);
std::int64_t window_count(const ScanGeometry& g);

struct WindowSlice {
  std::int64_t first_row = 0;  // of the window in the record
  int pixel_x = 0;             // column (a retrace runs right to left: its first dwell is the last column)
  int pixel_y = 0;             // line
  bool line_start = false;     // first window of its line
  // The window starts where the previous one ended in the record (a full-dwell window after
  // another in the same pass): INITIAL_CONTINUED; else INITIAL_UNKNOWN.
  bool continued = false;
};
// The index-th window in time order (0 .. window_count - 1).
WindowSlice window_slice(const ScanGeometry& g, std::int64_t index);

}  // namespace tipforce::import
