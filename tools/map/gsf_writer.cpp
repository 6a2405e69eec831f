#include "gsf_writer.hpp"

#include <cstdint>
#include <cstring>
#include <fstream>
#include <string>
#include <vector>

#include "map_error.hpp"
#include "quantity.hpp"

namespace tipforce::map {
namespace {
// Header values must not contain a NUL or a line break.
std::string clean(std::string s) {
  for (char& ch : s)
    if (ch == '\0' || ch == '\n' || ch == '\r') ch = ' ';
  return s;
}
}  // namespace

void write_gsf(const std::string& path, const Grid& g, const GsfMeta& meta) {
  std::string header = "Gwyddion Simple Field 1.0\n";
  header += "XRes = " + std::to_string(g.width) + "\n";
  header += "YRes = " + std::to_string(g.height) + "\n";
  header += "XReal = " + exact_number(meta.x_real) + "\n";
  header += "YReal = " + exact_number(meta.y_real) + "\n";
  header += "XYUnits = " + clean(meta.xy_units) + "\n";
  if (!meta.z_units.empty()) header += "ZUnits = " + clean(meta.z_units) + "\n";
  if (!meta.title.empty()) header += "Title = " + clean(meta.title) + "\n";
  for (const auto& [name, value] : meta.extra) header += clean(name) + " = " + clean(value) + "\n";
  header.append(4 - header.size() % 4, '\0');  // 1..4 NULs: data at a multiple of 4

  std::vector<char> data(g.v.size() * 4);
  for (std::size_t i = 0; i < g.v.size(); ++i) {
    const float f = static_cast<float>(g.v[i]);  // NaN stays NaN
    std::uint32_t bits;
    std::memcpy(&bits, &f, 4);
    for (int b = 0; b < 4; ++b) data[i * 4 + static_cast<std::size_t>(b)] = static_cast<char>((bits >> (8 * b)) & 0xFFu);
  }
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (!out) throw MapError("cannot write " + path);
  out.write(header.data(), static_cast<std::streamsize>(header.size()));
  out.write(data.data(), static_cast<std::streamsize>(data.size()));
  out.close();
  if (!out) throw MapError("cannot write " + path + " (disk full?)");
}
}  // namespace tipforce::map
