#include "plot_frame.hpp"

#include "quantity.hpp"

namespace tipforce::map {
namespace {
constexpr double kTitle = 16, kText = 13, kTick = 12;
constexpr Rgb kGridLine{225, 225, 225};
}  // namespace

void draw_plot_frame(Painter& p, const PlotFrame& f, const std::string& title, const std::string& xlabel,
                     const std::string& ylabel) {
  for (double t : f.y.ticks) {
    const double y = f.Y(t);
    p.line(f.px0, y, f.px0 + f.pw, y, kGridLine);
    p.line(f.px0 - 6, y, f.px0, y, kInk);
    p.text(f.px0 - 9, y - 8, format_number(t, 6), kTick, Align::right);
  }
  for (double t : f.x.ticks) {
    const double x = f.X(t);
    p.line(x, f.py0, x, f.py0 + f.ph, kGridLine);
    p.line(x, f.py0 + f.ph, x, f.py0 + f.ph + 6, kInk);
    p.text(x, f.py0 + f.ph + 9, format_number(t, 6), kTick, Align::centre);
  }
  p.frame_rect(f.px0, f.py0, f.pw, f.ph, kInk);
  if (!title.empty()) p.text(16, 16, title, kTitle, Align::left, kInk, true);
  p.text(f.px0 + f.pw / 2.0, f.py0 + f.ph + 30, xlabel, kText, Align::centre);
  p.text_vertical(f.px0 - 88, f.py0 + f.ph / 2.0, ylabel, kText);
}

}  // namespace tipforce::map
