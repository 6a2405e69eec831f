// Map images through Cairo and Pango (figure.hpp): the map as exact pixel blocks, physical axes
// and a scale bar when the scan size is known, a colour bar with round ticks over the robust
// range, clipped pixels marked, and a legend. Every image is written as PNG and PDF.
#include "map_image.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "figure.hpp"
#include "ticks.hpp"

namespace tipforce::map {
namespace {
constexpr int kMargin = 16;
constexpr double kTitlePx = 16, kTextPx = 13, kTickPx = 12;
constexpr int kLine = 19;       // px per legend line
constexpr int kBarW = 24;
constexpr int kMinBarH = 240;
constexpr int kTriangle = 12;   // height of the colour bar's clipping arrows
constexpr int kTickLen = 5;

// The prefix suits the colour range (what the bar shows), not an outlier beyond it.
DisplayUnit unit_for(const Quantity& q, const ValueRange& r) {
  const double max_abs = !r.any ? 0.0 : r.constant ? std::abs(r.data_min) : std::max(std::abs(r.lo), std::abs(r.hi));
  return display_unit(q.si_unit, max_abs);
}

// Units as typeset in a figure: the micro prefix, written "u" in files and summaries, as µ.
std::string typeset(const std::string& unit) {
  return unit.size() > 1 && unit[0] == 'u' ? "\u00b5" + unit.substr(1) : unit;
}

std::string typeset_suffix(const DisplayUnit& u) { return u.label.empty() ? "" : "[" + typeset(u.label) + "]"; }

std::string with_unit(double si, const DisplayUnit& u, int digits = 4) {
  std::string s = format_number(si * u.factor, digits);
  if (!u.label.empty()) s += " " + typeset(u.label);
  return s;
}

// The map at `scale` px per pixel: colours, hatched missing pixels, marked clipped ones.
Raster map_raster(const Grid& g, int scale, const ValueRange& r) {
  Raster out(g.width * scale, g.height * scale);
  for (int y = 0; y < g.height; ++y)
    for (int x = 0; x < g.width; ++x) {
      const double v = g.at(x, y);
      const int x0 = x * scale, y0 = y * scale;
      if (!std::isfinite(v) || !r.any) {
        out.fill(x0, y0, scale, scale, kNoEstimate);
        for (int j = 0; j < scale; ++j)
          for (int i = 0; i < scale; ++i)
            if (is_hatch_pixel(i, j, scale)) out.set(x0 + i, y0 + j, kNoEstimateHatch);
        continue;
      }
      out.fill(x0, y0, scale, scale, colour_of(v, r.lo, r.hi));
      if (v > r.hi || v < r.lo)
        for (int j = 0; j < scale; ++j)
          for (int i = 0; i < scale; ++i)
            if (is_clip_mark_pixel(i, j, scale)) out.set(x0 + i, y0 + j, v > r.hi ? kClippedAbove : kClippedBelow);
    }
  return out;
}

// The bar's rows: top = viridis[255], bottom = viridis[0].
Raster bar_raster(int h, bool any) {
  Raster out(kBarW, h);
  for (int row = 0; row < h; ++row) {
    const double t = h > 1 ? 1.0 - static_cast<double>(row) / (h - 1) : 0.5;
    const auto idx = static_cast<std::size_t>(std::clamp(std::lround(t * 255.0), 0L, 255L));
    out.fill(0, row, kBarW, 1, any ? viridis()[idx] : kNoEstimate);
  }
  return out;
}

struct BarLayout {
  std::vector<double> ticks;           // SI
  std::vector<std::string> labels;
  std::vector<int> ys;
  double label_width = 0;
};

BarLayout bar_layout(const ValueRange& r, const DisplayUnit& u, int bar_y0, int bar_h) {
  BarLayout b;
  if (!r.any) return b;
  if (r.constant) {
    b.ticks = {r.data_min};
    b.labels = {format_number(r.data_min * u.factor, 6)};
    b.ys = {bar_y0 + bar_h / 2};
  } else {
    const Ticks t = round_ticks(r.lo * u.factor, r.hi * u.factor, 6);
    for (double v : t.values) {
      b.ticks.push_back(v / u.factor);
      b.labels.push_back(tick_label(v, t.step));
      const double frac = (v / u.factor - r.lo) / (r.hi - r.lo);
      b.ys.push_back(bar_y0 + (bar_h - 1) - static_cast<int>(std::lround((bar_h - 1) * std::clamp(frac, 0.0, 1.0))));
    }
  }
  for (const auto& l : b.labels) b.label_width = std::max(b.label_width, measure_text(l, kTickPx).width);
  return b;
}

void draw_bar(Painter& p, int x, int y, int h, const ValueRange& r, const BarLayout& b) {
  p.image(x, y, bar_raster(h, r.any));
  p.frame_rect(x, y, kBarW, h, kInk);
  if (r.above > 0) p.triangle(x, y - 2, x + kBarW, y - 2, x + kBarW / 2.0, y - 2 - kTriangle, viridis()[255], kInk);
  if (r.below > 0)
    p.triangle(x, y + h + 2, x + kBarW, y + h + 2, x + kBarW / 2.0, y + h + 2 + kTriangle, viridis()[0], kInk);
  if (!r.any) {
    p.text(x + kBarW + 8, y, "no valid pixels", kTickPx);
    return;
  }
  for (std::size_t k = 0; k < b.ticks.size(); ++k) {
    p.line(x + kBarW, b.ys[k] + 0.5, x + kBarW + kTickLen, b.ys[k] + 0.5, kInk);
    const double th = measure_text(b.labels[k], kTickPx).height;
    p.text(x + kBarW + kTickLen + 3, b.ys[k] + 0.5 - th / 2, b.labels[k], kTickPx);
  }
}

// One axis of a map: its extent (display units), label and ticks.
struct MapAxis {
  double extent = 1;
  std::string label;
  Ticks ticks;
  double label_width = 0;  // widest tick label
};

MapAxis map_axis(double extent, const std::string& label) {
  MapAxis a;
  a.extent = extent;
  a.label = label;
  a.ticks = round_ticks(0, extent, 4);
  for (double v : a.ticks.values) a.label_width = std::max(a.label_width, measure_text(tick_label(v, a.ticks.step), kTickPx).width);
  return a;
}

struct Axes {
  MapAxis x, y;
  DisplayUnit unit;  // of both
  bool physical = false;
  double scale_bar_m = 0;
  std::string scale_bar_label;
};

// Physical axes in one length unit when the scan size is known, else pixel counts.
Axes make_axes(const ScanSize& scan, int w, int h) {
  Axes a;
  a.physical = scan.known();
  if (a.physical) {
    a.unit = display_unit("m", std::max(scan.x_m, scan.y_m));
    a.x = map_axis(scan.x_m * a.unit.factor, "x [" + typeset(a.unit.label) + "]");
    a.y = map_axis(scan.y_m * a.unit.factor, "y [" + typeset(a.unit.label) + "]");
    // The longest 1-2-5 length within a quarter of the width.
    const double quarter = scan.x_m / 4;
    const double mag = std::pow(10.0, std::floor(std::log10(quarter)));
    for (double m : {5.0, 2.0, 1.0})
      if (m * mag <= quarter * (1 + 1e-9)) {
        a.scale_bar_m = m * mag;
        break;
      }
    const DisplayUnit bu = display_unit("m", a.scale_bar_m);
    a.scale_bar_label = format_number(a.scale_bar_m * bu.factor, 3) + " " + typeset(bu.label);
  } else {
    a.x = map_axis(w, "x [pixels]");
    a.y = map_axis(h, "y [pixels]");
  }
  return a;
}

constexpr int kAxisBelow = kTickLen + 3 + 15 + 4 + 17;  // ticks, tick labels, axis label

int axes_left_width(const Axes& a) { return static_cast<int>(std::ceil(a.y.label_width)) + kTickLen + 3 + 20; }

void draw_axes(Painter& p, const Axes& a, int x0, int y0, int w, int h) {
  for (double v : a.x.ticks.values) {
    const double x = x0 + v / a.x.extent * w;
    p.line(x, y0 + h, x, y0 + h + kTickLen, kInk);
    p.text(x, y0 + h + kTickLen + 2, tick_label(v, a.x.ticks.step), kTickPx, Align::centre);
  }
  for (double v : a.y.ticks.values) {  // y grows downward: line 0 is the top row
    const double y = y0 + v / a.y.extent * h;
    p.line(x0 - kTickLen, y, x0, y, kInk);
    const double th = measure_text("0", kTickPx).height;
    p.text(x0 - kTickLen - 3, y - th / 2, tick_label(v, a.y.ticks.step), kTickPx, Align::right);
  }
  p.text(x0 + w / 2.0, y0 + h + kTickLen + 3 + 15 + 2, a.x.label, kTickPx, Align::centre);
  p.text_vertical(x0 - kTickLen - 3 - a.y.label_width - 12, y0 + h / 2.0, a.y.label, kTickPx);
  if (a.scale_bar_m > 0) {
    // Below the map at its right end, beside the x-axis label: it covers no data.
    const double len = a.scale_bar_m / (a.x.extent / a.unit.factor) * w;
    const double by = y0 + h + kTickLen + 3 + 15 + 10;
    p.fill_rect(x0 + w - len, by, len, 4, kInk);
    p.text(x0 + w - len - 6, by - 7, a.scale_bar_label, kTickPx, Align::right);
  }
}

void draw_swatch(Painter& p, int x, int y, Rgb c, bool hatched) {
  constexpr int s = 14;
  Raster r(s, s, c);
  if (hatched)
    for (int j = 0; j < s; ++j)
      for (int i = 0; i < s; ++i)
        if (is_hatch_pixel(i, j, 7)) r.set(i, j, kNoEstimateHatch);
  p.image(x, y + 2, r);
  p.frame_rect(x, y + 2, s, s, kInk);
}

std::size_t count_missing(const Grid& g) {
  return static_cast<std::size_t>(std::count_if(g.v.begin(), g.v.end(), [](double v) { return !std::isfinite(v); }));
}

std::string scan_line(const ScanSize& scan, int w, int h) {
  const std::string px = std::to_string(w) + " x " + std::to_string(h) + " pixels";
  if (!scan.known()) return "scan size unknown: axes count pixels (" + px + "; pixel_y 0 at the top)";
  const DisplayUnit u = display_unit("m", std::max(scan.x_m, scan.y_m));
  return "scan " + format_number(scan.x_m * u.factor, 4) + " \u00d7 " + format_number(scan.y_m * u.factor, 4) + " " +
         typeset(u.label) + ", " + px + " (line 0 at the top)";
}

int text_w(const std::string& s, double px = kTextPx, bool bold = false) {
  return static_cast<int>(std::ceil(measure_text(s, px, bold).width));
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

bool is_clip_mark_pixel(int i, int j, int scale) {
  if (scale < 4) return false;
  const int side = std::max(2, scale / 3);
  const int lo = (scale - side) / 2;
  return i >= lo && i < lo + side && j >= lo && j < lo + side;
}

MapImageInfo write_map_png(const std::string& path, const QuantityMap& m, const std::string& subtitle,
                           const ScanSize& scan) {
  const Grid g = scaled(m.grid, m.quantity.display_factor);
  MapImageInfo info;
  info.path = path;
  info.pdf_path = pdf_path_for(path);
  info.key = m.quantity.key;
  info.grid_width = g.width;
  info.grid_height = g.height;
  info.display_factor = m.quantity.display_factor;
  info.scale = map_scale(g.width, g.height);
  info.range = value_range(g);
  info.unit = unit_for(m.quantity, info.range);
  const Axes axes = make_axes(scan, g.width, g.height);
  info.physical_axes = axes.physical;
  info.scale_bar_m = axes.scale_bar_m;

  const int map_w = g.width * info.scale, map_h = g.height * info.scale;
  const std::string unit_br = typeset_suffix(info.unit);
  const std::string title = m.quantity.key + ": " + m.quantity.title + (unit_br.empty() ? "" : " " + unit_br);
  const int top = kMargin + 22 + 10;
  info.map_x0 = kMargin + axes_left_width(axes);
  info.map_y0 = top + (info.range.above > 0 ? kTriangle + 2 : 0);
  info.bar_x0 = info.map_x0 + map_w + 28;
  info.bar_y0 = info.map_y0;
  info.bar_w = kBarW;
  info.bar_h = std::max(map_h, kMinBarH);
  const BarLayout bar = bar_layout(info.range, info.unit, info.bar_y0, info.bar_h);
  info.tick_values = bar.ticks;
  info.tick_labels = bar.labels;
  info.tick_y = bar.ys;
  const std::string bar_label = (m.quantity.display_factor < 0 ? "-" : "") + m.quantity.key +
                                (unit_br.empty() ? " (no unit)" : " " + unit_br);
  const int bar_label_x = info.bar_x0 + kBarW + kTickLen + 3 + static_cast<int>(std::ceil(bar.label_width)) + 12;

  const std::size_t missing = count_missing(g);
  std::vector<std::string> lines;
  lines.push_back("no estimate: " + std::to_string(missing) + " of " +
                  std::to_string(static_cast<std::size_t>(g.width) * static_cast<std::size_t>(g.height)) + " pixels");
  if (!info.range.any)
    lines.push_back("no valid value in any pixel");
  else if (info.range.constant)
    lines.push_back("constant: " + with_unit(info.range.data_min, info.unit, 6));
  else {
    std::string l = "data " + with_unit(info.range.data_min, info.unit) + " to " + with_unit(info.range.data_max, info.unit);
    if (info.range.below + info.range.above > 0)
      l += "; colour range " + with_unit(info.range.lo, info.unit) + " to " + with_unit(info.range.hi, info.unit) +
           " (1st-99th percentile)";
    lines.push_back(l);
  }
  const bool clipped = info.range.below + info.range.above > 0;
  if (clipped)
    lines.push_back("marked pixels lie outside the colour range: " + std::to_string(info.range.above) +
                    " above (black mark), " + std::to_string(info.range.below) + " below (white mark)");
  lines.push_back(scan_line(scan, g.width, g.height));
  if (!subtitle.empty()) lines.push_back(subtitle);
  if (!m.quantity.note.empty()) lines.push_back(m.quantity.note);

  int width = bar_label_x + 18;
  width = std::max(width, kMargin + text_w(title, kTitlePx, true));
  for (const auto& l : lines) width = std::max(width, kMargin + 22 + text_w(l));
  width += kMargin;
  const int body_bottom = std::max(info.map_y0 + map_h + kAxisBelow + 8,
                                   info.bar_y0 + info.bar_h + (info.range.below > 0 ? kTriangle + 4 : 0));
  const int legend_y = body_bottom + 12;
  const int height = legend_y + static_cast<int>(lines.size()) * kLine + kMargin;

  const Raster raster = map_raster(g, info.scale, info.range);
  write_figure(path, width, height, [&](Painter& p) {
    p.text(kMargin, kMargin, title, kTitlePx, Align::left, kInk, true);
    p.image(info.map_x0, info.map_y0, raster);
    p.frame_rect(info.map_x0, info.map_y0, map_w, map_h, kInk);
    draw_axes(p, axes, info.map_x0, info.map_y0, map_w, map_h);
    draw_bar(p, info.bar_x0, info.bar_y0, info.bar_h, info.range, bar);
    p.text_vertical(bar_label_x, info.bar_y0 + info.bar_h / 2.0, bar_label, kTextPx);
    int y = legend_y;
    draw_swatch(p, kMargin, y, kNoEstimate, true);
    p.text(kMargin + 22, y, lines[0], kTextPx);
    for (std::size_t i = 1; i < lines.size(); ++i) {
      y += kLine;
      if (clipped && i == 2) {
        Raster mark(14, 14, viridis()[255]);
        mark.fill(5, 5, 4, 4, kClippedAbove);
        p.image(kMargin, y + 2, mark);
        p.frame_rect(kMargin, y + 2, 14, 14, kInk);
      }
      p.text(kMargin + 22, y, lines[i], kTextPx);
    }
  });
  info.width = width;
  info.height = height;
  return info;
}

MapImageInfo write_status_png(const std::string& path, const Grid& status, const std::string& subtitle,
                              const ScanSize& scan) {
  MapImageInfo info;
  info.path = path;
  info.pdf_path = pdf_path_for(path);
  info.key = "status";
  info.grid_width = status.width;
  info.grid_height = status.height;
  info.scale = map_scale(status.width, status.height);
  const Axes axes = make_axes(scan, status.width, status.height);
  info.physical_axes = axes.physical;
  info.scale_bar_m = axes.scale_bar_m;
  const int map_w = status.width * info.scale, map_h = status.height * info.scale;
  info.map_x0 = kMargin + axes_left_width(axes);
  info.map_y0 = kMargin + 22 + 10;

  std::size_t n_ok = 0, n_nc = 0, n_rej = 0, n_missing = 0;
  Raster raster(map_w, map_h);
  for (int y = 0; y < status.height; ++y)
    for (int x = 0; x < status.width; ++x) {
      const double v = status.at(x, y);
      const int x0 = x * info.scale, y0 = y * info.scale;
      if (!std::isfinite(v)) {
        ++n_missing;
        raster.fill(x0, y0, info.scale, info.scale, kNoEstimate);
        for (int j = 0; j < info.scale; ++j)
          for (int i = 0; i < info.scale; ++i)
            if (is_hatch_pixel(i, j, info.scale)) raster.set(x0 + i, y0 + j, kNoEstimateHatch);
        continue;
      }
      if (v == 0) ++n_ok;
      else if (v == 1) ++n_nc;
      else ++n_rej;
      raster.fill(x0, y0, info.scale, info.scale, v == 0 ? kStatusOk : v == 1 ? kStatusNotConverged : kStatusRejected);
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
      {kNoEstimate, true, "no estimate: " + std::to_string(n_missing)},
  };
  const int legend_x = info.map_x0 + map_w + 28;
  int width = kMargin + text_w(title, kTitlePx, true);
  for (const auto& e : legend) width = std::max(width, legend_x + 22 + text_w(e.label));
  const std::vector<std::string> lines{scan_line(scan, status.width, status.height), subtitle};
  for (const auto& l : lines) width = std::max(width, kMargin + text_w(l));
  width += kMargin;
  const int body_bottom = std::max(info.map_y0 + map_h + kAxisBelow + 8, info.map_y0 + 4 * (kLine + 6));
  const int lines_y = body_bottom + 12;
  const int height = lines_y + static_cast<int>(lines.size()) * kLine + kMargin;
  write_figure(path, width, height, [&](Painter& p) {
    p.text(kMargin, kMargin, title, kTitlePx, Align::left, kInk, true);
    p.image(info.map_x0, info.map_y0, raster);
    p.frame_rect(info.map_x0, info.map_y0, map_w, map_h, kInk);
    draw_axes(p, axes, info.map_x0, info.map_y0, map_w, map_h);
    for (std::size_t i = 0; i < legend.size(); ++i) {
      const int y = info.map_y0 + static_cast<int>(i) * (kLine + 6);
      draw_swatch(p, legend_x, y, legend[i].colour, legend[i].missing);
      p.text(legend_x + 22, y, legend[i].label, kTextPx);
    }
    for (std::size_t i = 0; i < lines.size(); ++i) p.text(kMargin, lines_y + static_cast<int>(i) * kLine, lines[i], kTextPx);
  });
  info.width = width;
  info.height = height;
  return info;
}

ComparisonImageInfo write_comparison_png(const std::string& path, const Quantity& q, const Grid& truth_raw,
                                         const Grid& estimate_raw, const Grid& difference_raw) {
  const Grid truth = scaled(truth_raw, q.display_factor), estimate = scaled(estimate_raw, q.display_factor),
             difference = scaled(difference_raw, q.display_factor);
  ComparisonImageInfo info;
  info.path = path;
  const int w = truth.width, h = truth.height;
  info.scale = map_scale(w, h, 256);
  info.shared = value_range(std::vector<const Grid*>{&truth, &estimate});
  info.unit = unit_for(q, info.shared);
  ValueRange d = value_range(difference);
  if (d.any) {  // symmetric around zero so that "no error" sits mid-scale
    const double m = std::max(std::abs(d.lo), std::abs(d.hi));
    if (m > 0) {
      d.lo = -m;
      d.hi = m;
      d.constant = false;
      d.below = d.above = 0;
      for (double v : difference.v)
        if (std::isfinite(v)) {
          if (v < d.lo) ++d.below;
          if (v > d.hi) ++d.above;
        }
    }
  }
  info.diff = d;

  const int pw = w * info.scale, ph = h * info.scale;
  const int bar_h = std::max(ph, kMinBarH);
  const int top = kMargin + 22 + kLine + 8;
  info.panel_y0 = top + kTriangle + 2;
  info.panel_x0[0] = kMargin;
  info.panel_x0[1] = info.panel_x0[0] + pw + 16;
  const int bar1_x = info.panel_x0[1] + pw + 22;
  const BarLayout bar1 = bar_layout(info.shared, info.unit, info.panel_y0, bar_h);
  info.panel_x0[2] = bar1_x + kBarW + kTickLen + 3 + static_cast<int>(std::ceil(bar1.label_width)) + 30;
  const int bar2_x = info.panel_x0[2] + pw + 22;
  const BarLayout bar2 = bar_layout(info.diff, info.unit, info.panel_y0, bar_h);
  const int right = bar2_x + kBarW + kTickLen + 3 + static_cast<int>(std::ceil(bar2.label_width));

  const std::string unit_br = typeset_suffix(info.unit);
  const std::string shown = q.display_factor < 0 ? " (shown as -" + q.key + ")" : "";
  const std::string title = q.key + ": truth | estimate | estimate - truth" + shown + (unit_br.empty() ? "" : " " + unit_br);
  std::vector<std::string> lines{"grey: no estimate or no truth; truth and estimate share one colour scale",
                                 "pixel_x 0.." + std::to_string(w - 1) + " left to right, pixel_y 0.." +
                                     std::to_string(h - 1) + " top to bottom"};
  if (info.shared.below + info.shared.above + info.diff.below + info.diff.above > 0)
    lines.push_back("marked pixels lie outside their colour range (1st-99th percentile): black above, white below");
  int width = std::max(right, kMargin + text_w(title, kTitlePx, true));
  for (const auto& l : lines) width = std::max(width, kMargin + 22 + text_w(l));
  width += kMargin;
  const int lines_y = info.panel_y0 + std::max(ph, bar_h) + kTriangle + 16;
  const int height = lines_y + static_cast<int>(lines.size()) * kLine + kMargin;

  const std::array<const char*, 3> names{"truth", "estimate", "difference"};
  const std::array<const Grid*, 3> grids{&truth, &estimate, &difference};
  write_figure(path, width, height, [&](Painter& p) {
    p.text(kMargin, kMargin, title, kTitlePx, Align::left, kInk, true);
    for (std::size_t k = 0; k < 3; ++k) {
      p.text(info.panel_x0[k], top - 4, names[k], kTextPx);
      p.image(info.panel_x0[k], info.panel_y0, map_raster(*grids[k], info.scale, k < 2 ? info.shared : info.diff));
      p.frame_rect(info.panel_x0[k], info.panel_y0, pw, ph, kInk);
    }
    draw_bar(p, bar1_x, info.panel_y0, bar_h, info.shared, bar1);
    draw_bar(p, bar2_x, info.panel_y0, bar_h, info.diff, bar2);
    draw_swatch(p, kMargin, lines_y, kNoEstimate, true);
    for (std::size_t i = 0; i < lines.size(); ++i) p.text(kMargin + 22, lines_y + static_cast<int>(i) * kLine, lines[i], kTextPx);
  });
  info.width = width;
  info.height = height;
  return info;
}
}  // namespace tipforce::map
