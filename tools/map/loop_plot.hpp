#pragma once
// Peak force per pixel along a scan line, several runs against one limit: the closed-loop
// example's figure (issue 13, README "Closing the loop", made by ctest loop.e2e.ClosedLoop).
#include <string>
#include <vector>

#include "colormap.hpp"

namespace tipforce::map {

struct PixelSeries {
  std::string label;
  std::vector<double> values_n;  // one per pixel, N
  Rgb colour;
};

// One line per series (nN against pixel), the limit dashed, the pixels with `shaded` set
// (e.g. the hard domains) on a grey background named `shaded_label` in the legend. Writes the
// PNG and the PDF beside it; throws MapError when it cannot.
void write_peak_force_per_pixel(const std::string& png_path, const std::string& title,
                                const std::vector<PixelSeries>& series, double limit_n, const std::vector<bool>& shaded,
                                const std::string& shaded_label);

}  // namespace tipforce::map
