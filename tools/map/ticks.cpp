#include "ticks.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

namespace tipforce::map {
namespace {
double step_for(double span, int target) {
  const double raw = span / std::max(1, target);
  const double mag = std::pow(10.0, std::floor(std::log10(raw)));
  for (double m : {1.0, 2.0, 5.0, 10.0})
    if (raw <= m * mag * (1 + 1e-9)) return m * mag;
  return 10 * mag;
}
}  // namespace

Ticks round_ticks(double lo, double hi, int target) {
  Ticks t;
  if (!(hi > lo) || !std::isfinite(lo) || !std::isfinite(hi)) {
    if (std::isfinite(lo)) t.values.push_back(lo);
    return t;
  }
  // Two ticks inside at least: a range little wider than one step may hold only one.
  for (int n = std::max(1, target); n <= 64; n *= 2) {
    t.step = step_for(hi - lo, n);
    if (std::floor(hi / t.step + 1e-9) - std::ceil(lo / t.step - 1e-9) >= 1) break;
  }
  const long long first = static_cast<long long>(std::ceil(lo / t.step - 1e-9));
  const long long last = static_cast<long long>(std::floor(hi / t.step + 1e-9));
  for (long long k = first; k <= last; ++k) {
    const double v = static_cast<double>(k) * t.step;
    t.values.push_back(std::abs(v) < t.step * 1e-9 ? 0.0 : v);
  }
  return t;
}

Axis nice_axis(double lo, double hi, bool from_zero) {
  if (from_zero) lo = std::min(lo, 0.0);
  if (!(hi > lo)) {
    const double pad = lo != 0 ? std::abs(lo) * 0.1 : 1.0;
    lo -= pad;
    hi += pad;
    if (from_zero && lo < 0 && hi > 0 && lo > -pad * 2) lo = 0;
  }
  const double step = step_for(hi - lo, 7);
  Axis a;
  a.lo = std::floor(lo / step) * step;
  a.hi = std::ceil(hi / step) * step;
  for (double t = a.lo; t <= a.hi + step * 0.5; t += step) a.ticks.push_back(std::abs(t) < step * 1e-9 ? 0.0 : t);
  return a;
}

std::string tick_label(double value, double step) {
  const int decimals = std::clamp(static_cast<int>(-std::floor(std::log10(step) + 1e-9)), 0, 12);
  char b[64];
  std::snprintf(b, sizeof b, "%.*f", decimals, value);
  std::string s = b;
  if (s.find_first_not_of("-0.") == std::string::npos) s = "0";
  return s;
}

}  // namespace tipforce::map
