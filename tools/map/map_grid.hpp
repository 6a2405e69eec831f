#pragma once
#include <cstddef>
#include <string>
#include <utility>
#include <vector>

#include <tipforce/force_estimate_t.hpp>

#include "quantity.hpp"

namespace tipforce::map {
// A width x height map, row-major, row 0 = pixel_y 0 (top of the image). NaN = no value.
struct Grid {
  int width = 0;
  int height = 0;
  std::vector<double> v;

  Grid() = default;
  Grid(int w, int h);
  double at(int x, int y) const { return v[static_cast<std::size_t>(y) * static_cast<std::size_t>(width) + static_cast<std::size_t>(x)]; }
  double& at(int x, int y) { return v[static_cast<std::size_t>(y) * static_cast<std::size_t>(width) + static_cast<std::size_t>(x)]; }
};

// The colour-scale range of a map, robust so that one outlier does not flatten it: from the
// 1st to the 99th percentile of its finite values (tipforce::percentile, nearest rank), reaching
// out to the smallest and largest values that lie within 10 % of that span beyond them. So
// nothing is clipped for being the noisiest pixel of a flat region, while a real outlier is.
// Pixels outside lo..hi are drawn in the end colour and marked (below, above count them). A
// constant map gets a tiny symmetric range around its value (constant = true); no finite value:
// any = false.
struct ValueRange {
  double lo = 0.0;
  double hi = 1.0;
  double data_min = 0.0;
  double data_max = 0.0;
  bool constant = false;
  bool any = false;
  std::size_t valid = 0;  // finite pixels
  std::size_t below = 0;  // finite pixels < lo (clipped)
  std::size_t above = 0;  // finite pixels > hi (clipped)
};
// The fraction of the percentile span within which an extreme value widens the range instead of
// being clipped.
inline constexpr double kRangeReach = 0.1;
ValueRange value_range(const Grid& g);
ValueRange value_range(const std::vector<const Grid*>& grids);  // shared scale
// The grid with every value multiplied by `factor` (height shown as -h).
Grid scaled(const Grid& g, double factor);

struct QuantityMap {
  Quantity quantity;
  Grid grid;
};

// All per-pixel maps of a set of estimates (one probe).
struct MapSet {
  int width = 0;   // max pixel_x + 1, or the scan's width if larger
  int height = 0;  // max pixel_y + 1, or the scan's height if larger
  std::vector<int> estimate_index;        // per pixel: index into the estimates, -1 = none
  std::vector<std::string> param_names;   // union over the estimates, first-seen order
  std::vector<QuantityMap> maps;          // params, their sigmas, derived quantities, misfit
  Grid status;                            // status code per pixel, NaN = no estimate
  std::size_t duplicates = 0;             // estimates replaced by a later one for the same pixel
  std::size_t negative_pixels = 0;        // estimates with pixel_x or pixel_y < 0 (ignored)
  std::vector<std::pair<int, int>> missing;   // (x, y) without any estimate, row-major order
  std::vector<std::pair<int, int>> rejected;  // (x, y) whose estimate is STATUS_REJECTED (or unknown)
};

// Throws MapError when no estimate has a valid pixel or the map would be absurdly large. The map
// covers at least scan_width x scan_height pixels (the scan's geometry, when known), so that
// pixels after the last estimate (a log cut short) count as missing too.
MapSet build_maps(const std::vector<tipforce::force_estimate_t>& estimates, int scan_width = 0, int scan_height = 0);

// Value of parameter `name` (or its sigma) in one estimate; NaN when absent or non-finite.
double param_value(const tipforce::force_estimate_t& e, const std::string& name, bool sigma = false);
}  // namespace tipforce::map
