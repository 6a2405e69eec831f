#include "loop_plot.hpp"

#include <algorithm>
#include <cmath>

#include "figure.hpp"
#include "plot_frame.hpp"
#include "ticks.hpp"

namespace tipforce::map {
namespace {
constexpr double kText = 13;
constexpr int kW = 1000, kH = 520;
constexpr int kLeft = 110, kRight = 30, kTop = 60, kBottom = 70;
constexpr Rgb kShade{232, 232, 232};
constexpr Rgb kLimit{215, 48, 39};
}  // namespace

void write_peak_force_per_pixel(const std::string& png_path, const std::string& title,
                                const std::vector<PixelSeries>& series, double limit_n, const std::vector<bool>& shaded,
                                const std::string& shaded_label) {
  std::size_t n = shaded.size();
  double top = limit_n;
  for (const PixelSeries& s : series) {
    n = std::max(n, s.values_n.size());
    for (double v : s.values_n)
      if (std::isfinite(v)) top = std::max(top, v);
  }
  PlotFrame f;
  f.px0 = kLeft;
  f.py0 = kTop;
  f.pw = kW - kLeft - kRight;
  f.ph = kH - kTop - kBottom;
  // The axis ends with the line (half a pixel past its last), not at the next round number.
  f.x = nice_axis(0, static_cast<double>(std::max<std::size_t>(n, 2) - 1), true);
  f.x.lo = -0.5;
  f.x.hi = static_cast<double>(std::max<std::size_t>(n, 2)) - 0.5;
  f.x.ticks.erase(std::remove_if(f.x.ticks.begin(), f.x.ticks.end(), [&](double t) { return t > f.x.hi; }),
                  f.x.ticks.end());
  f.y = nice_axis(0, top * 1e9 * 1.05, true);
  write_figure(png_path, kW, kH, [&](Painter& p) {
    // The shading first, under the grid: one rectangle per run of shaded pixels (one per pixel
    // would leave antialiased seams between them).
    for (std::size_t i = 0; i < shaded.size();) {
      if (!shaded[i]) {
        ++i;
        continue;
      }
      std::size_t j = i;
      while (j < shaded.size() && shaded[j]) ++j;
      const double x0 = std::max(f.X(static_cast<double>(i) - 0.5), double(f.px0));
      const double x1 = std::min(f.X(static_cast<double>(j) - 0.5), double(f.px0 + f.pw));
      p.fill_rect(x0, f.py0, x1 - x0, f.ph, kShade);
      i = j;
    }
    draw_plot_frame(p, f, title, "pixel", "true peak force [nN]");
    p.clip(f.px0, f.py0, f.pw, f.ph);
    const double yl = f.Y(limit_n * 1e9);
    for (double x = f.px0; x < f.px0 + f.pw; x += 10) p.line(x, yl, std::min(x + 6.0, double(f.px0 + f.pw)), yl, kLimit, 1.5);
    for (const PixelSeries& s : series) {
      std::vector<std::pair<double, double>> pts;
      for (std::size_t i = 0; i < s.values_n.size(); ++i)
        if (std::isfinite(s.values_n[i])) pts.emplace_back(f.X(static_cast<double>(i)), f.Y(s.values_n[i] * 1e9));
      p.polyline(pts, s.colour, 1.6);
      for (const auto& [x, y] : pts) p.dot(x, y, 1.8, s.colour);
    }
    p.unclip();
    // Legend, top right inside the plot.
    const double lw = 250, lh = 24.0 * (static_cast<double>(series.size()) + 2) + 4;
    const double lx = f.px0 + f.pw - lw - 10, ly = f.py0 + 8;
    p.fill_rect(lx, ly, lw, lh, kBackground);
    p.frame_rect(lx, ly, lw, lh, kInk);
    double y = ly + 6;
    for (const PixelSeries& s : series) {
      p.line(lx + 8, y + 8, lx + 30, y + 8, s.colour, 2.0);
      p.text(lx + 38, y, s.label, kText);
      y += 24;
    }
    p.line(lx + 8, y + 8, lx + 30, y + 8, kLimit, 1.5);
    p.text(lx + 38, y, "limit", kText);
    y += 24;
    p.fill_rect(lx + 8, y + 2, 22, 12, kShade);
    p.frame_rect(lx + 8, y + 2, 22, 12, kInk, 0.5);
    p.text(lx + 38, y, shaded_label, kText);
  });
}

}  // namespace tipforce::map
