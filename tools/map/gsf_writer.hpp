#pragma once
#include <string>
#include <utility>
#include <vector>

#include "map_grid.hpp"

namespace tipforce::map {
struct GsfMeta {
  double x_real = 1.0;  // physical width (XRes * pixel size), in xy_units
  double y_real = 1.0;
  std::string xy_units = "m";
  std::string z_units;  // SI unit without prefix ("N/m", "m", "N", "J"); "" = dimensionless
  std::string title;
  // Further "Name = value" lines; Gwyddion shows them as the channel's metadata.
  std::vector<std::pair<std::string, std::string>> extra;
};

// Gwyddion Simple Field file (http://gwyddion.net/documentation/user-guide-en/gsf.html):
// the line "Gwyddion Simple Field 1.0", "Name = value" lines (LF), 1..4 NUL bytes so that the
// data starts at a multiple of 4, then XRes*YRes little-endian float32 values row by row from
// the top-left. Missing pixels are NaN (Gwyddion masks them on import).
// Throws MapError naming the file when it cannot write.
void write_gsf(const std::string& path, const Grid& g, const GsfMeta& meta);
}  // namespace tipforce::map
