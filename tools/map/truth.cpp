#include "truth.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>

#include "tipforce/percentile.hpp"
#include "map_error.hpp"

namespace tipforce::map {
namespace {
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

std::string trim(std::string s) {
  const auto b = s.find_first_not_of(" \t\r\n\"");
  const auto e = s.find_last_not_of(" \t\r\n\"");
  return b == std::string::npos ? std::string() : s.substr(b, e - b + 1);
}

std::vector<std::string> split(const std::string& line) {
  std::vector<std::string> out;
  std::string cell;
  std::stringstream ss(line);
  while (std::getline(ss, cell, ',')) out.push_back(trim(cell));
  if (!line.empty() && line.back() == ',') out.emplace_back();
  return out;
}

bool parse_double(const std::string& s, double& v) {
  if (s.empty()) return false;
  const char* b = s.data();
  if (*b == '+') ++b;
  const auto res = std::from_chars(b, s.data() + s.size(), v);
  return res.ec == std::errc() && res.ptr == s.data() + s.size();
}

bool parse_int(const std::string& s, int& v) {
  double d;
  if (!parse_double(s, d) || d != std::floor(d) || std::abs(d) > 1e9) return false;
  v = static_cast<int>(d);
  return true;
}

// The grid of estimate-side values, resized to w x h.
Grid resized(const Grid& g, int w, int h) {
  Grid out(w, h);
  for (int y = 0; y < std::min(h, g.height); ++y)
    for (int x = 0; x < std::min(w, g.width); ++x) out.at(x, y) = g.at(x, y);
  return out;
}

const Grid* find_grid(const MapSet& ms, const std::string& key) {
  for (const auto& m : ms.maps)
    if (m.quantity.key == key) return &m.grid;
  return nullptr;
}
}  // namespace

TruthTable read_truth_csv(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw MapInputError("cannot read truth file " + path);
  std::string line;
  if (!std::getline(in, line)) throw MapInputError("truth file " + path + " is empty");
  const auto header = split(line);
  int col_x = -1, col_y = -1, col_seq = -1;
  std::vector<int> param_cols;
  TruthTable t;
  for (std::size_t i = 0; i < header.size(); ++i) {
    if (header[i] == "pixel_x") col_x = static_cast<int>(i);
    else if (header[i] == "pixel_y") col_y = static_cast<int>(i);
    else if (header[i] == "seq") col_seq = static_cast<int>(i);
    else if (header[i].empty()) continue;
    else {
      t.params.push_back(header[i]);
      param_cols.push_back(static_cast<int>(i));
    }
  }
  if (col_x < 0 || col_y < 0)
    throw MapInputError("truth file " + path + ": header lacks pixel_x / pixel_y (expected seq,pixel_x,pixel_y,<params>)");
  // A row that cannot be read is refused, not skipped: a skipped row drops its pixel from the
  // accuracy figures, and a silently NaN cell or a second row for a pixel changes them unseen.
  std::map<std::pair<int, int>, std::size_t> first_line;  // pixel -> the line that gave it
  std::size_t line_no = 1;
  while (std::getline(in, line)) {
    ++line_no;
    if (trim(line).empty()) continue;
    const std::string where = "truth file " + path + ": line " + std::to_string(line_no) + ": ";
    const auto cells = split(line);
    if (cells.size() != header.size())
      throw MapInputError(where + std::to_string(cells.size()) + " cells, the header has " +
                          std::to_string(header.size()) + " (" + line + ")");
    auto cell = [&](int col) -> const std::string& { return cells[static_cast<std::size_t>(col)]; };
    int x = -1, y = -1, seq = 0;
    if (!parse_int(cell(col_x), x) || x < 0)
      throw MapInputError(where + "pixel_x \"" + cell(col_x) + "\" is not a pixel index (a whole number >= 0)");
    if (!parse_int(cell(col_y), y) || y < 0)
      throw MapInputError(where + "pixel_y \"" + cell(col_y) + "\" is not a pixel index (a whole number >= 0)");
    if (col_seq >= 0 && !parse_int(cell(col_seq), seq))
      throw MapInputError(where + "seq \"" + cell(col_seq) + "\" is not a whole number");
    std::vector<double> vals(t.params.size(), kNaN);
    for (std::size_t k = 0; k < param_cols.size(); ++k) {
      double v;
      if (!parse_double(cell(param_cols[k]), v) || !std::isfinite(v))
        throw MapInputError(where + t.params[k] + " \"" + cell(param_cols[k]) + "\" is not a finite number");
      vals[k] = v;
    }
    const auto [it, fresh] = first_line.emplace(std::make_pair(x, y), line_no);
    if (!fresh)
      throw MapInputError(where + "pixel (" + std::to_string(x) + ", " + std::to_string(y) +
                          ") again; line " + std::to_string(it->second) + " already gave its truth");
    ++t.rows;
    t.values[{x, y}] = std::move(vals);
    t.width = std::max(t.width, x + 1);
    t.height = std::max(t.height, y + 1);
  }
  if (t.values.empty()) throw MapInputError("truth file " + path + " has no rows after its header");
  // Its grid is allocated beside the map's: the same bound as build_maps'.
  if (static_cast<long long>(t.width) * t.height > 64LL * 1024 * 1024)
    throw MapInputError("truth file " + path + ": pixels up to (" + std::to_string(t.width - 1) + ", " +
                        std::to_string(t.height - 1) + ") span more than the 64 Mpixel a map may have");
  return t;
}

std::vector<ParamAccuracy> compare_with_truth(const TruthTable& truth, const MapSet& ms, const std::string& out_dir,
                                              std::vector<std::string>* only_truth) {
  std::vector<ParamAccuracy> out;
  const int w = std::max(truth.width, ms.width), h = std::max(truth.height, ms.height);
  for (std::size_t k = 0; k < truth.params.size(); ++k) {
    const std::string& name = truth.params[k];
    const Grid* est_g = find_grid(ms, name);
    const Grid* sig_g = find_grid(ms, name + "_sigma");
    if (est_g == nullptr || sig_g == nullptr ||
        std::find(ms.param_names.begin(), ms.param_names.end(), name) == ms.param_names.end()) {
      if (only_truth) only_truth->push_back(name);
      continue;
    }
    Grid tg(w, h), diff(w, h);
    for (const auto& [xy, vals] : truth.values) tg.at(xy.first, xy.second) = vals[k];
    const Grid eg = resized(*est_g, w, h), sg = resized(*sig_g, w, h);
    ParamAccuracy acc;
    acc.name = name;
    auto figures = [&](bool ok_only) {
      TruthFigures f;
      std::vector<double> rel, rel_sigma, sigmas;
      std::size_t within = 0;
      for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
          const double tv = tg.at(x, y), ev = eg.at(x, y), sv = sg.at(x, y);
          if (!std::isfinite(tv) || !std::isfinite(ev)) continue;
          if (ok_only && !(x < ms.width && y < ms.height && ms.status.at(x, y) == tipforce::force_estimate_t::STATUS_OK))
            continue;
          ++f.compared;
          const double err = std::abs(ev - tv);
          if (!ok_only) diff.at(x, y) = ev - tv;
          if (tv != 0.0) rel.push_back(err / std::abs(tv));
          if (std::isfinite(sv) && err <= 2.0 * sv) ++within;
          if (std::isfinite(sv)) {
            sigmas.push_back(sv);
            if (ev != 0.0) rel_sigma.push_back(sv / std::abs(ev));
          }
        }
      f.median_rel_err = percentile(rel, 0.5);
      f.p90_rel_err = percentile(rel, 0.9);
      f.median_rel_sigma = percentile(rel_sigma, 0.5);
      const double median_sigma = percentile(sigmas, 0.5);
      f.max_over_median_sigma =
          sigmas.empty() || median_sigma <= 0 ? kNaN : *std::max_element(sigmas.begin(), sigmas.end()) / median_sigma;
      f.frac_within_2sigma = f.compared ? static_cast<double>(within) / static_cast<double>(f.compared) : kNaN;
      return f;
    };
    static_cast<TruthFigures&>(acc) = figures(false);
    acc.ok = figures(true);
    acc.comparison_png = (std::filesystem::path(out_dir) / ("truth_" + name + ".png")).string();
    acc.image = write_comparison_png(acc.comparison_png, param_quantity(name), tg, eg, diff);
    out.push_back(std::move(acc));
  }
  return out;
}
}  // namespace tipforce::map
