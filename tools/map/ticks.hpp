#pragma once
// Round tick values (1, 2 or 5 x 10^k steps) for every axis and colour bar of `tipforce map`.
#include <string>
#include <vector>

namespace tipforce::map {

struct Ticks {
  double step = 1;
  std::vector<double> values;  // ascending
};

// Ticks at multiples of a 1-2-5 step that lie within [lo, hi] (about `target` of them; at least
// two when hi > lo). lo == hi gives the one value.
Ticks round_ticks(double lo, double hi, int target = 5);

// The axis limits widened outward to the next multiples of the step, with the ticks between
// (plots whose limits are free: histograms, time series). from_zero includes 0.
struct Axis {
  double lo = 0, hi = 1;
  std::vector<double> ticks;
};
Axis nice_axis(double lo, double hi, bool from_zero);

// A tick's label: as many decimals as the step needs ("2.5", "10", "0.05"), -0 as 0.
std::string tick_label(double value, double step);

}  // namespace tipforce::map
