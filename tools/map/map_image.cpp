#include "map_image.hpp"

#include <algorithm>
#include <cmath>

#include "bitmap_font.hpp"
#include "colormap.hpp"
#include "png_writer.hpp"

namespace tipforce::map {
namespace {
constexpr int kMargin = 14;
constexpr int kText = 2;                        // font scale of every label
constexpr int kLine = kLineHeight * kText + 2;  // 22 px per text line
constexpr int kBarW = 24;
constexpr int kMinBarH = 240;
constexpr int kTicks = 5;

// Labels for the tick values, with just enough digits that neighbours differ.
std::vector<std::string> tick_labels(const std::vector<double>& shown, bool constant) {
  std::vector<std::string> labels;
  for (int digits = 3; digits <= 9; ++digits) {
    labels.clear();
    for (double v : shown) labels.push_back(format_number(v, digits));
    bool distinct = true;
    for (std::size_t i = 1; i < labels.size(); ++i) distinct = distinct && labels[i] != labels[i - 1];
    if (distinct || constant) break;
  }
  return labels;
}

DisplayUnit unit_for(const Quantity& q, const ValueRange& r) {
  const double max_abs = r.any ? std::max(std::abs(r.data_min), std::abs(r.data_max)) : 0.0;
  return display_unit(q.si_unit, max_abs);
}

std::string with_unit(double si, const DisplayUnit& u, int digits = 4) {
  std::string s = format_number(si * u.factor, digits);
  if (!u.label.empty()) s += " " + u.label;
  return s;
}

void draw_missing_block(Canvas& c, int x0, int y0, int scale) {
  c.fill_rect(x0, y0, scale, scale, kNoEstimate);
  if (scale < 6) return;
  for (int j = 0; j < scale; ++j)
    for (int i = 0; i < scale; ++i)
      if (is_hatch_pixel(i, j, scale)) c.set(x0 + i, y0 + j, kNoEstimateHatch);
}

void draw_grid(Canvas& c, int x0, int y0, const Grid& g, int scale, const ValueRange& r) {
  for (int y = 0; y < g.height; ++y)
    for (int x = 0; x < g.width; ++x) {
      const double v = g.at(x, y);
      if (std::isfinite(v) && r.any)
        c.fill_rect(x0 + x * scale, y0 + y * scale, scale, scale, colour_of(v, r.lo, r.hi));
      else
        draw_missing_block(c, x0 + x * scale, y0 + y * scale, scale);
    }
}

struct BarResult {
  int right = 0;  // right edge of the tick labels
  std::vector<double> ticks;
  std::vector<std::string> labels;
};

// Vertical colour bar (top = hi) with kTicks labelled ticks on its right.
BarResult draw_colour_bar(Canvas& c, int x, int y, int h, const ValueRange& r, const DisplayUnit& u) {
  BarResult out;
  if (!r.any) {
    c.fill_rect(x, y, kBarW, h, kNoEstimate);
    c.frame_rect(x - 1, y - 1, kBarW + 2, h + 2, kInk);
    c.text(x + kBarW + 8, y, "no valid", kInk, kText);
    c.text(x + kBarW + 8, y + kLine, "pixels", kInk, kText);
    out.right = x + kBarW + 8 + text_width("no valid", kText);
    return out;
  }
  for (int row = 0; row < h; ++row) {
    const double t = h > 1 ? 1.0 - static_cast<double>(row) / (h - 1) : 0.5;
    const auto idx = static_cast<std::size_t>(std::clamp(std::lround(t * 255.0), 0L, 255L));
    c.hline(x, x + kBarW - 1, y + row, viridis()[idx]);
  }
  c.frame_rect(x - 1, y - 1, kBarW + 2, h + 2, kInk);
  // A constant map has one tick, mid-bar, at its value; otherwise kTicks from lo to hi.
  const int n_ticks = r.constant ? 1 : kTicks;
  std::vector<double> shown;
  for (int k = 0; k < n_ticks; ++k) {
    const double v = r.constant ? r.data_min : r.lo + (r.hi - r.lo) * k / (kTicks - 1);
    out.ticks.push_back(v);
    shown.push_back(v * u.factor);
  }
  out.labels = tick_labels(shown, r.constant);
  out.right = x + kBarW;
  const int glyph_h = kGlyphHeight * kText;
  for (int k = 0; k < n_ticks; ++k) {
    const double frac = r.constant ? 0.5 : static_cast<double>(k) / (kTicks - 1);
    const int ty = y + (h - 1) - static_cast<int>(std::lround(static_cast<double>(h - 1) * frac));
    c.hline(x + kBarW, x + kBarW + 5, ty, kInk);
    const int lx = x + kBarW + 9;
    c.text(lx, ty - glyph_h / 2 + 1, out.labels[static_cast<std::size_t>(k)], kInk, kText);
    out.right = std::max(out.right, lx + text_width(out.labels[static_cast<std::size_t>(k)], kText));
  }
  return out;
}

// One legend line with a colour swatch (hatched for the no-estimate colour).
int legend_swatch(Canvas& c, int x, int y, Rgb colour, bool missing, const std::string& label) {
  const int s = kGlyphHeight * kText;
  if (missing)
    draw_missing_block(c, x, y, s);
  else
    c.fill_rect(x, y, s, s, colour);
  c.frame_rect(x, y, s, s, kInk);
  c.text(x + s + 8, y, label, kInk, kText);
  return x + s + 8 + text_width(label, kText);
}

std::string pixel_axes_line(int w, int h) {
  return "pixel_x 0.." + std::to_string(w - 1) + " left to right, pixel_y 0.." + std::to_string(h - 1) +
         " top to bottom";
}

std::size_t count_missing(const Grid& g) {
  return static_cast<std::size_t>(std::count_if(g.v.begin(), g.v.end(), [](double v) { return !std::isfinite(v); }));
}
}  // namespace

int map_scale(int w, int h, int target) {
  const int side = std::max({w, h, 1});
  return std::max(1, (target + side - 1) / side);
}

bool is_hatch_pixel(int i, int j, int scale) {
  if (scale < 6) return false;
  return (i + j) % 6 == 0 || (i - j) % 6 == 0;
}

MapImageInfo write_map_png(const std::string& path, const QuantityMap& m, const std::string& subtitle) {
  const Grid& g = m.grid;
  MapImageInfo info;
  info.path = path;
  info.key = m.quantity.key;
  info.grid_width = g.width;
  info.grid_height = g.height;
  info.scale = map_scale(g.width, g.height);
  info.range = value_range(g);
  info.unit = unit_for(m.quantity, info.range);

  const int map_w = g.width * info.scale, map_h = g.height * info.scale;
  info.map_x0 = kMargin;
  info.map_y0 = kMargin + 2 * kLine + 8;
  info.bar_x0 = info.map_x0 + map_w + 22;
  info.bar_y0 = info.map_y0;
  info.bar_w = kBarW;
  info.bar_h = std::max(map_h, kMinBarH);

  const std::string unit_br = unit_suffix(info.unit);
  const std::string title = m.quantity.key + ": " + m.quantity.title + (unit_br.empty() ? "" : " " + unit_br);
  const std::string bar_label = m.quantity.key + (unit_br.empty() ? " (no unit)" : " " + unit_br);
  const std::size_t missing = count_missing(g);
  std::vector<std::string> lines;
  lines.push_back("grey: no estimate (" + std::to_string(missing) + " of " +
                  std::to_string(static_cast<std::size_t>(g.width) * static_cast<std::size_t>(g.height)) + " px)");
  if (!info.range.any)
    lines.push_back("no valid value in any pixel");
  else if (info.range.constant)
    lines.push_back("constant: " + with_unit(info.range.data_min, info.unit, 6));
  else
    lines.push_back("min " + with_unit(info.range.data_min, info.unit) + ", max " +
                    with_unit(info.range.data_max, info.unit));
  lines.push_back(pixel_axes_line(g.width, g.height));
  if (!subtitle.empty()) lines.push_back(subtitle);
  if (!m.quantity.note.empty()) lines.push_back(m.quantity.note);

  // Size: measure first, draw second (a throwaway canvas measures the bar's labels).
  Canvas probe(1, 1);
  const BarResult measured = draw_colour_bar(probe, info.bar_x0, info.bar_y0, info.bar_h, info.range, info.unit);
  int width = std::max(measured.right, info.bar_x0 + text_width(bar_label, kText));
  width = std::max(width, kMargin + text_width(title, kText));
  for (const auto& l : lines) width = std::max(width, kMargin + kGlyphHeight * kText + 8 + text_width(l, kText));
  width += kMargin;
  const int legend_y = info.map_y0 + std::max(map_h, info.bar_h) + 14;
  const int height = legend_y + static_cast<int>(lines.size()) * kLine + kMargin;

  Canvas c(width, height);
  c.text(kMargin, kMargin, title, kInk, kText);
  c.text(info.bar_x0, kMargin + kLine + 4, bar_label, kInk, kText);
  draw_grid(c, info.map_x0, info.map_y0, g, info.scale, info.range);
  c.frame_rect(info.map_x0 - 1, info.map_y0 - 1, map_w + 2, map_h + 2, kInk);
  const BarResult bar = draw_colour_bar(c, info.bar_x0, info.bar_y0, info.bar_h, info.range, info.unit);
  info.tick_values = bar.ticks;
  info.tick_labels = bar.labels;
  int y = legend_y;
  legend_swatch(c, kMargin, y, kNoEstimate, true, lines[0]);
  for (std::size_t i = 1; i < lines.size(); ++i) c.text(kMargin, y + static_cast<int>(i) * kLine, lines[i], kInk, kText);
  write_png(path, c);
  info.width = c.width();
  info.height = c.height();
  return info;
}

MapImageInfo write_status_png(const std::string& path, const Grid& status, const std::string& subtitle) {
  MapImageInfo info;
  info.path = path;
  info.key = "status";
  info.grid_width = status.width;
  info.grid_height = status.height;
  info.scale = map_scale(status.width, status.height);
  const int map_w = status.width * info.scale, map_h = status.height * info.scale;
  info.map_x0 = kMargin;
  info.map_y0 = kMargin + 2 * kLine + 8;

  std::size_t n_ok = 0, n_nc = 0, n_rej = 0, n_missing = 0;
  for (double v : status.v) {
    if (!std::isfinite(v)) ++n_missing;
    else if (v == 0) ++n_ok;
    else if (v == 1) ++n_nc;
    else ++n_rej;
  }
  const std::string title = "status: fit status per pixel";
  struct Entry {
    Rgb colour;
    bool missing;
    std::string label;
  };
  const std::vector<Entry> legend{
      {kStatusOk, false, "ok: " + std::to_string(n_ok)},
      {kStatusNotConverged, false, "not converged: " + std::to_string(n_nc)},
      {kStatusRejected, false, "rejected: " + std::to_string(n_rej)},
      {kNoEstimate, true, "grey: no estimate: " + std::to_string(n_missing)},
  };
  const int legend_x = info.map_x0 + map_w + 22;
  int width = kMargin + text_width(title, kText);
  for (const auto& e : legend)
    width = std::max(width, legend_x + kGlyphHeight * kText + 8 + text_width(e.label, kText));
  std::vector<std::string> lines{pixel_axes_line(status.width, status.height)};
  if (!subtitle.empty()) lines.push_back(subtitle);
  for (const auto& l : lines) width = std::max(width, kMargin + text_width(l, kText));
  width += kMargin;
  const int body_h = std::max(map_h, static_cast<int>(legend.size()) * (kLine + 8));
  const int lines_y = info.map_y0 + body_h + 14;
  const int height = lines_y + static_cast<int>(lines.size()) * kLine + kMargin;

  Canvas c(width, height);
  c.text(kMargin, kMargin, title, kInk, kText);
  for (int y = 0; y < status.height; ++y)
    for (int x = 0; x < status.width; ++x) {
      const double v = status.at(x, y);
      const int px = info.map_x0 + x * info.scale, py = info.map_y0 + y * info.scale;
      if (!std::isfinite(v)) draw_missing_block(c, px, py, info.scale);
      else c.fill_rect(px, py, info.scale, info.scale, v == 0 ? kStatusOk : v == 1 ? kStatusNotConverged : kStatusRejected);
    }
  c.frame_rect(info.map_x0 - 1, info.map_y0 - 1, map_w + 2, map_h + 2, kInk);
  for (std::size_t i = 0; i < legend.size(); ++i)
    legend_swatch(c, legend_x, info.map_y0 + static_cast<int>(i) * (kLine + 8), legend[i].colour, legend[i].missing,
                  legend[i].label);
  for (std::size_t i = 0; i < lines.size(); ++i) c.text(kMargin, lines_y + static_cast<int>(i) * kLine, lines[i], kInk, kText);
  write_png(path, c);
  info.width = c.width();
  info.height = c.height();
  return info;
}

ComparisonImageInfo write_comparison_png(const std::string& path, const Quantity& q, const Grid& truth,
                                         const Grid& estimate, const Grid& difference) {
  ComparisonImageInfo info;
  info.path = path;
  const int w = truth.width, h = truth.height;
  info.scale = map_scale(w, h, 256);
  info.shared = value_range(std::vector<const Grid*>{&truth, &estimate});
  info.unit = unit_for(q, info.shared);
  ValueRange d = value_range(difference);
  if (d.any) {  // symmetric around zero so that "no error" sits mid-scale
    const double m = std::max(std::abs(d.data_min), std::abs(d.data_max));
    if (m > 0) {
      d.lo = -m;
      d.hi = m;
      d.constant = false;
    }
  }
  info.diff = d;

  const int pw = w * info.scale, ph = h * info.scale;
  const int bar_h = std::max(ph, kMinBarH);
  info.panel_y0 = kMargin + 2 * kLine + 8;
  info.panel_x0[0] = kMargin;
  info.panel_x0[1] = info.panel_x0[0] + pw + 16;
  const int bar1_x = info.panel_x0[1] + pw + 22;
  Canvas probe(1, 1);
  const int bar1_right = draw_colour_bar(probe, bar1_x, info.panel_y0, bar_h, info.shared, info.unit).right;
  info.panel_x0[2] = bar1_right + 30;
  const int bar2_x = info.panel_x0[2] + pw + 22;
  const int bar2_right = draw_colour_bar(probe, bar2_x, info.panel_y0, bar_h, info.diff, info.unit).right;

  const std::string unit_br = unit_suffix(info.unit);
  const std::string title = q.key + ": truth | estimate | estimate - truth" + (unit_br.empty() ? "" : " " + unit_br);
  const std::vector<std::string> lines{
      "grey: no estimate or no truth; truth and estimate share one colour scale",
      pixel_axes_line(w, h)};
  int width = std::max(bar2_right, kMargin + text_width(title, kText));
  for (const auto& l : lines) width = std::max(width, kMargin + kGlyphHeight * kText + 8 + text_width(l, kText));
  width += kMargin;
  const int lines_y = info.panel_y0 + std::max(ph, bar_h) + 14;
  const int height = lines_y + static_cast<int>(lines.size()) * kLine + kMargin;

  Canvas c(width, height);
  c.text(kMargin, kMargin, title, kInk, kText);
  const std::array<const char*, 3> names{"truth", "estimate", "difference"};
  const std::array<const Grid*, 3> grids{&truth, &estimate, &difference};
  for (int p = 0; p < 3; ++p) {
    c.text(info.panel_x0[static_cast<std::size_t>(p)], kMargin + kLine + 4, names[static_cast<std::size_t>(p)], kInk, kText);
    draw_grid(c, info.panel_x0[static_cast<std::size_t>(p)], info.panel_y0, *grids[static_cast<std::size_t>(p)], info.scale,
              p < 2 ? info.shared : info.diff);
    c.frame_rect(info.panel_x0[static_cast<std::size_t>(p)] - 1, info.panel_y0 - 1, pw + 2, ph + 2, kInk);
  }
  draw_colour_bar(c, bar1_x, info.panel_y0, bar_h, info.shared, info.unit);
  draw_colour_bar(c, bar2_x, info.panel_y0, bar_h, info.diff, info.unit);
  legend_swatch(c, kMargin, lines_y, kNoEstimate, true, lines[0]);
  c.text(kMargin, lines_y + kLine, lines[1], kInk, kText);
  write_png(path, c);
  info.width = c.width();
  info.height = c.height();
  return info;
}
}  // namespace tipforce::map
