#pragma once
#include <array>
#include <cstddef>
#include <string>
#include <vector>

#include "colormap.hpp"
#include "map_grid.hpp"
#include "quantity.hpp"

namespace tipforce::map {
// Integer magnification so that the larger side of a w x h map is at least `target` px
// (1 when it already is).
int map_scale(int w, int h, int target = 384);

// The scanned area, from the log's scan_geometry_t (tipforce import) or --scan-size-m; 0 =
// unknown, and the axes count pixels.
struct ScanSize {
  double x_m = 0, y_m = 0;
  bool known() const { return x_m > 0 && y_m > 0; }
};

// Marks on clipped pixels (outside the colour range, drawn in the range's end colour): black on
// the bright end, white on the dark end, so that each shows against its colour.
inline constexpr Rgb kClippedAbove{0, 0, 0};
inline constexpr Rgb kClippedBelow{255, 255, 255};

// Where and how a map was drawn, so callers (and tests) need not guess positions in the image.
struct MapImageInfo {
  std::string path;            // the PNG; the PDF is beside it (pdf_path)
  std::string pdf_path;
  std::string key;
  int width = 0, height = 0;   // PNG size
  int map_x0 = 0, map_y0 = 0;  // PNG position of the top-left corner of map pixel (0, 0)
  int scale = 1;               // PNG pixels per map pixel (square blocks)
  int grid_width = 0, grid_height = 0;
  double display_factor = 1;   // the map shows display_factor x the estimate (-1 for h: height)
  ValueRange range;            // colour range of the shown values, SI (viridis[0] at lo, [255] at hi)
  DisplayUnit unit;            // how the bar's labels are written
  std::vector<double> tick_values;         // SI, ascending; one (the value) if constant
  std::vector<std::string> tick_labels;    // as printed, in `unit`
  std::vector<int> tick_y;                 // PNG row of each tick on the bar
  int bar_x0 = 0, bar_y0 = 0, bar_w = 0, bar_h = 0;  // colour bar: top row = hi, bottom = lo
  bool physical_axes = false;  // axes in metres (scan size known) or in pixels
  double scale_bar_m = 0;      // length of the scale bar, 0 = none
};

// Pixels of a no-estimate block at local offset (i, j) inside a block of `scale` px that carry
// the cross-hatch colour (only when scale >= 6); all others are kNoEstimate.
bool is_hatch_pixel(int i, int j, int scale);
// Pixels of a clipped block at local offset (i, j) that carry the clip mark: a centred square of
// side max(2, scale / 3) (none when scale < 4).
bool is_clip_mark_pixel(int i, int j, int scale);

// A quantity map with axes (physical with a scale bar when the scan size is known), a colour bar
// with round ticks over the robust range, and a legend. Writes PATH (PNG) and PATH with .pdf.
// Throws MapError when it cannot write.
MapImageInfo write_map_png(const std::string& path, const QuantityMap& m, const std::string& subtitle,
                           const ScanSize& scan = {});

// The status map: three discrete colours plus the no-estimate colour, with a legend.
MapImageInfo write_status_png(const std::string& path, const Grid& status, const std::string& subtitle,
                              const ScanSize& scan = {});

// Truth | estimate | estimate - truth, the first two on one shared colour scale, all shown with
// the quantity's display factor.
struct ComparisonImageInfo {
  std::string path;
  int width = 0, height = 0;
  int scale = 1;
  std::array<int, 3> panel_x0{};  // truth, estimate, difference
  int panel_y0 = 0;
  ValueRange shared;  // truth and estimate
  ValueRange diff;    // symmetric around 0
  DisplayUnit unit;
};
ComparisonImageInfo write_comparison_png(const std::string& path, const Quantity& q, const Grid& truth,
                                         const Grid& estimate, const Grid& difference);
}  // namespace tipforce::map
