#include "scan_layout.hpp"

#include <string>

#include "import_error.hpp"
#include "tipforce/window.hpp"

namespace tipforce::import {

void check_geometry(const ScanGeometry& g) {
  // Bounds that keep every product below int64 and every window within what tipforce inverts.
  auto need = [](bool ok, const std::string& what) {
    if (!ok) throw ImportError(what);
  };
  need(g.samples_per_pixel >= 1 && g.samples_per_pixel <= 100'000'000,
       "--samples-per-pixel must be 1 to 100000000, got " + std::to_string(g.samples_per_pixel));
  need(g.pixels_per_line >= 1 && g.pixels_per_line <= 65536,
       "--pixels-per-line must be 1 to 65536, got " + std::to_string(g.pixels_per_line));
  need(g.lines >= 1 && g.lines <= 65536, "--lines must be 1 to 65536, got " + std::to_string(g.lines));
  need(g.window_offset >= 0 && g.window_offset < g.samples_per_pixel,
       "--window-offset must lie within the dwell (0 to " + std::to_string(g.samples_per_pixel - 1) + "), got " +
           std::to_string(g.window_offset));
  need(g.window_length >= 0 && g.window_offset + g.window_length <= g.samples_per_pixel,
       "--window-offset + --window-length (" + std::to_string(g.window_offset) + " + " +
           std::to_string(g.window_length) + ") runs past the dwell of " + std::to_string(g.samples_per_pixel) +
           " samples");
  need(window_length(g) <= kMaxWindowSamples, "a window of " + std::to_string(window_length(g)) +
                                                  " samples is more than tipforce inverts (" +
                                                  std::to_string(kMaxWindowSamples) + "); give --window-length");
  // Shorter windows are written, then rejected by every reader (window_problem_for_probe).
  need(window_length(g) >= WindowLimits{}.min_samples,
       g.window_length > 0 ? "--window-length must be " + window_length_range() + ", got " +
                                 std::to_string(g.window_length)
                           : "a window of " + std::to_string(window_length(g)) +
                                 " samples (--samples-per-pixel - --window-offset) is fewer than tipforce inverts; "
                                 "windows must be " + window_length_range());
  need(g.skip_samples >= 0 && g.skip_samples <= (std::int64_t{1} << 50), "--skip-samples must be >= 0");
  need(g.line_gap_samples >= 0 && g.line_gap_samples <= (std::int64_t{1} << 40), "--line-gap-samples must be >= 0");
  need(!g.keep_retrace || g.trace_and_retrace, "--keep retrace needs --line-layout trace-retrace");
}

std::string window_length_range() {
  return std::to_string(WindowLimits{}.min_samples) + " to " + std::to_string(kMaxWindowSamples) + " samples";
}

std::int64_t window_length(const ScanGeometry& g) {
  return g.window_length > 0 ? g.window_length : g.samples_per_pixel - g.window_offset;
}

namespace {
std::int64_t pass_rows(const ScanGeometry& g) { return g.samples_per_pixel * g.pixels_per_line; }
std::int64_t line_stride(const ScanGeometry& g) {
  return pass_rows(g) * (g.trace_and_retrace ? 2 : 1) + g.line_gap_samples;
}
}  // namespace

std::int64_t record_rows_needed(const ScanGeometry& g) {
  return g.skip_samples + line_stride(g) * g.lines - g.line_gap_samples;
}

std::int64_t window_count(const ScanGeometry& g) {
  return static_cast<std::int64_t>(g.pixels_per_line) * g.lines;
}

WindowSlice window_slice(const ScanGeometry& g, std::int64_t index) {
  WindowSlice s;
  const int line = static_cast<int>(index / g.pixels_per_line);
  const int dwell = static_cast<int>(index % g.pixels_per_line);  // in time order within the pass
  const std::int64_t pass_start =
      g.skip_samples + line_stride(g) * line + (g.keep_retrace ? pass_rows(g) : 0);
  s.first_row = pass_start + g.samples_per_pixel * dwell + g.window_offset;
  s.pixel_y = line;
  s.pixel_x = g.keep_retrace ? g.pixels_per_line - 1 - dwell : dwell;
  s.line_start = dwell == 0;
  s.continued = dwell > 0 && window_length(g) == g.samples_per_pixel;
  return s;
}

}  // namespace tipforce::import
