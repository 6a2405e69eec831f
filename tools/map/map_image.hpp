#pragma once
#include <array>
#include <cstddef>
#include <string>
#include <vector>

#include "canvas.hpp"
#include "map_grid.hpp"
#include "quantity.hpp"

namespace tipforce::map {
// Integer magnification so that the larger side of a w x h map is at least `target` px
// (1 when it already is).
int map_scale(int w, int h, int target = 384);

// Where and how a map was drawn, so callers (and tests) need not read the image back.
struct MapImageInfo {
  std::string path;
  std::string key;
  int width = 0, height = 0;   // PNG size
  int map_x0 = 0, map_y0 = 0;  // PNG position of the top-left corner of map pixel (0, 0)
  int scale = 1;               // PNG pixels per map pixel (square blocks)
  int grid_width = 0, grid_height = 0;
  ValueRange range;            // colour-bar range in SI units (viridis[0] at lo, [255] at hi)
  DisplayUnit unit;            // how the bar's labels are written
  std::vector<double> tick_values;         // SI, bottom (lo) to top (hi); one (the value) if constant
  std::vector<std::string> tick_labels;    // as printed, in `unit`
  int bar_x0 = 0, bar_y0 = 0, bar_w = 0, bar_h = 0;  // colour bar: top row = hi, bottom = lo
};

// Pixels of a no-estimate block at local offset (i, j) inside a block of `scale` px that carry
// the cross-hatch colour (only when scale >= 6); all others are kNoEstimate.
bool is_hatch_pixel(int i, int j, int scale);

// A quantity map with its colour bar, legend and title. Throws MapError when it cannot write.
MapImageInfo write_map_png(const std::string& path, const QuantityMap& m, const std::string& subtitle);

// The status map: three discrete colours plus the no-estimate colour, with a legend.
MapImageInfo write_status_png(const std::string& path, const Grid& status, const std::string& subtitle);

// Truth | estimate | estimate - truth, the first two on one shared colour scale.
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
