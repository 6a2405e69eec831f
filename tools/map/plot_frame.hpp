#pragma once
// An x-y plot's frame on a Painter: axes with round ticks, grid lines, labels. Shared by the
// latency plots and `tipforce inspect`.
#include <string>

#include "figure.hpp"
#include "ticks.hpp"

namespace tipforce::map {

struct PlotFrame {
  Axis x, y;
  int px0 = 0, py0 = 0, pw = 1, ph = 1;  // the plotting area in the figure
  double X(double v) const { return px0 + (v - x.lo) / (x.hi - x.lo) * pw; }
  double Y(double v) const { return py0 + ph - (v - y.lo) / (y.hi - y.lo) * ph; }
};

// Grid, ticks with labels, the frame, the x label below and the y label turned along the left.
// An empty title draws none.
void draw_plot_frame(Painter& p, const PlotFrame& f, const std::string& title, const std::string& xlabel,
                     const std::string& ylabel);

}  // namespace tipforce::map
