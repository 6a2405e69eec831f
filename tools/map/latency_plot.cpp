#include "latency_plot.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <tuple>
#include <utility>

#include "bitmap_font.hpp"
#include "canvas.hpp"
#include "png_writer.hpp"
#include "quantity.hpp"

namespace tipforce::map {
namespace {
constexpr int kText = 2;
constexpr int kW = 900, kH = 560;
constexpr int kLeft = 120, kRight = 50, kTop = 84, kBottom = 80;
constexpr Rgb kPoints{49, 104, 142};   // viridis blue
constexpr Rgb kP50{53, 183, 121};      // viridis green
constexpr Rgb kP99{215, 48, 39};
constexpr Rgb kGridLine{225, 225, 225};

struct Axis {
  double lo = 0, hi = 1;
  std::vector<double> ticks;
};

// "Nice" axis over lo..hi: steps of 1, 2 or 5 x 10^k, about 5-8 ticks, limits on ticks.
Axis nice_axis(double lo, double hi, bool from_zero) {
  if (from_zero) lo = std::min(lo, 0.0);
  if (!(hi > lo)) {
    const double pad = lo != 0 ? std::abs(lo) * 0.1 : 1.0;
    lo -= pad;
    hi += pad;
    if (from_zero && lo < 0 && hi > 0 && lo > -pad * 2) lo = 0;
  }
  const double raw = (hi - lo) / 7.0;
  const double mag = std::pow(10.0, std::floor(std::log10(raw)));
  double step = mag;
  for (double m : {1.0, 2.0, 5.0, 10.0})
    if (raw <= m * mag) {
      step = m * mag;
      break;
    }
  Axis a;
  a.lo = std::floor(lo / step) * step;
  a.hi = std::ceil(hi / step) * step;
  for (double t = a.lo; t <= a.hi + step * 0.5; t += step) a.ticks.push_back(std::abs(t) < step * 1e-9 ? 0.0 : t);
  return a;
}

struct Frame {
  Axis x, y;
  int px0 = kLeft, py0 = kTop, pw = kW - kLeft - kRight, ph = kH - kTop - kBottom;
  int X(double v) const { return px0 + static_cast<int>(std::lround((v - x.lo) / (x.hi - x.lo) * (pw - 1))); }
  int Y(double v) const { return py0 + ph - 1 - static_cast<int>(std::lround((v - y.lo) / (y.hi - y.lo) * (ph - 1))); }
};

void draw_frame(Canvas& c, const Frame& f, const std::string& title, const std::string& xlabel,
                const std::string& ylabel) {
  const int gh = kGlyphHeight * kText;
  for (double t : f.y.ticks) {
    const int y = f.Y(t);
    c.hline(f.px0, f.px0 + f.pw - 1, y, kGridLine);
    c.hline(f.px0 - 6, f.px0 - 1, y, kInk);
    const std::string s = format_number(t, 6);
    c.text(f.px0 - 10 - text_width(s, kText), y - gh / 2 + 1, s, kInk, kText);
  }
  for (double t : f.x.ticks) {
    const int x = f.X(t);
    c.vline(x, f.py0, f.py0 + f.ph - 1, kGridLine);
    c.vline(x, f.py0 + f.ph, f.py0 + f.ph + 5, kInk);
    const std::string s = format_number(t, 6);
    c.text(x - text_width(s, kText) / 2, f.py0 + f.ph + 10, s, kInk, kText);
  }
  c.frame_rect(f.px0 - 1, f.py0 - 1, f.pw + 2, f.ph + 2, kInk);
  c.text(12, 12, title, kInk, kText);
  c.text(f.px0 + (f.pw - text_width(xlabel, kText)) / 2, f.py0 + f.ph + 10 + gh + 12, xlabel, kInk, kText);
  // The y label sits above the axis (the font is not rotated).
  c.text(12, f.py0 - gh - 10, ylabel, kInk, kText);
}

std::vector<double> latencies(const std::vector<tipforce::force_estimate_t>& estimates) {
  std::vector<double> out;
  for (const auto& e : estimates)
    if (e.receive_utime != 0 && e.publish_utime != 0) out.push_back(static_cast<double>(e.publish_utime - e.receive_utime));
  return out;
}
}  // namespace

double percentile(std::vector<double> v, double q) {
  if (v.empty()) return std::numeric_limits<double>::quiet_NaN();
  std::sort(v.begin(), v.end());
  const double pos = std::clamp(q, 0.0, 1.0) * static_cast<double>(v.size() - 1);
  const auto i = static_cast<std::size_t>(std::floor(pos));
  const std::size_t j = std::min(i + 1, v.size() - 1);
  return v[i] + (v[j] - v[i]) * (pos - static_cast<double>(i));
}

std::optional<LatencySummary> summarize_latency(const std::vector<tipforce::force_estimate_t>& estimates) {
  const auto lat = latencies(estimates);
  if (lat.empty()) return std::nullopt;
  LatencySummary s;
  s.n = lat.size();
  s.min_us = *std::min_element(lat.begin(), lat.end());
  s.max_us = *std::max_element(lat.begin(), lat.end());
  s.p50_us = percentile(lat, 0.5);
  s.p90_us = percentile(lat, 0.9);
  s.p99_us = percentile(lat, 0.99);
  s.negative = static_cast<std::size_t>(std::count_if(lat.begin(), lat.end(), [](double v) { return v < 0; }));
  return s;
}

void write_latency_histogram(const std::string& path, const std::vector<tipforce::force_estimate_t>& estimates,
                             const LatencySummary& s) {
  const auto lat = latencies(estimates);
  const int bins = std::clamp(static_cast<int>(std::ceil(std::sqrt(static_cast<double>(lat.size())))), 10, 60);
  double lo = s.min_us, hi = s.max_us;
  if (!(hi > lo)) {
    lo -= 0.5;
    hi += 0.5;
  }
  const double width = (hi - lo) / bins;
  std::vector<std::size_t> counts(static_cast<std::size_t>(bins), 0);
  for (double v : lat) {
    const int b = std::clamp(static_cast<int>((v - lo) / width), 0, bins - 1);
    ++counts[static_cast<std::size_t>(b)];
  }
  const double max_count = static_cast<double>(*std::max_element(counts.begin(), counts.end()));

  Frame f;
  f.x = nice_axis(lo, hi, false);
  f.y = nice_axis(0, max_count, true);
  const std::string title = "receive -> publish latency: " + std::to_string(s.n) + " estimates, p50 " +
                            format_us(s.p50_us) + " us, p99 " + format_us(s.p99_us) + " us";
  Canvas c(std::max(kW, 24 + text_width(title, kText)), kH);
  draw_frame(c, f, title, "latency [us]", "estimates per bin");
  for (int b = 0; b < bins; ++b) {
    const double b0 = lo + width * b, b1 = b0 + width;
    const int x0 = f.X(b0), x1 = std::max(f.X(b1) - 1, x0);
    const int y0 = f.Y(static_cast<double>(counts[static_cast<std::size_t>(b)])), y1 = f.Y(0);
    if (counts[static_cast<std::size_t>(b)] == 0) continue;
    c.fill_rect(x0, y0, x1 - x0 + 1, y1 - y0 + 1, kPoints);
    c.frame_rect(x0, y0, x1 - x0 + 1, y1 - y0 + 1, kInk);
  }
  struct Marker {
    double v;
    Rgb colour;
    const char* name;
    int dy;
  };
  for (const Marker& m : {Marker{s.p50_us, kP50, "p50", 4}, Marker{s.p99_us, kP99, "p99", 26}}) {
    const int x = f.X(m.v);
    for (int y = f.py0; y < f.py0 + f.ph; y += 6) c.vline(x, y, y + 3, m.colour);
    c.text(x + 4, f.py0 + m.dy, m.name, m.colour, kText);
  }
  write_png(path, c);
}

void write_latency_over_time(const std::string& path, const std::vector<tipforce::force_estimate_t>& estimates,
                             const std::vector<tipforce::latency_stats_t>& stats) {
  std::int64_t t0 = std::numeric_limits<std::int64_t>::max();
  for (const auto& e : estimates)
    if (e.receive_utime != 0 && e.publish_utime != 0) t0 = std::min(t0, e.receive_utime);
  std::vector<std::pair<double, double>> pts;
  for (const auto& e : estimates)
    if (e.receive_utime != 0 && e.publish_utime != 0)
      pts.emplace_back(static_cast<double>(e.receive_utime - t0) * 1e-6, static_cast<double>(e.publish_utime - e.receive_utime));
  std::vector<std::tuple<double, double, double>> st;  // t, p50, p99
  for (const auto& m : stats)
    if (m.utime != 0 && std::isfinite(m.latency_p50_us) && std::isfinite(m.latency_p99_us) && m.windows_done > 0)
      st.emplace_back(static_cast<double>(m.utime - t0) * 1e-6, m.latency_p50_us, m.latency_p99_us);
  std::sort(st.begin(), st.end());

  double xlo = 0, xhi = 0, ylo = 0, yhi = 0;
  bool first = true;
  auto grow = [&](double x, double y) {
    if (first) {
      xlo = xhi = x;
      ylo = yhi = y;
      first = false;
    }
    xlo = std::min(xlo, x);
    xhi = std::max(xhi, x);
    ylo = std::min(ylo, y);
    yhi = std::max(yhi, y);
  };
  for (const auto& [x, y] : pts) grow(x, y);
  for (const auto& [x, p50, p99] : st) {
    grow(x, p50);
    grow(x, p99);
  }
  Frame f;
  f.x = nice_axis(xlo, xhi, true);
  f.y = nice_axis(ylo, yhi, true);
  Canvas c(kW, kH);
  draw_frame(c, f, "latency over time (" + std::to_string(pts.size()) + " estimates)",
             "time since first receive [s]", "receive -> publish latency [us]");
  for (const auto& [x, y] : pts) c.fill_rect(f.X(x) - 1, f.Y(y) - 1, 3, 3, kPoints);
  for (std::size_t i = 0; i < st.size(); ++i) {
    const auto& [x, p50, p99] = st[i];
    c.fill_rect(f.X(x) - 2, f.Y(p50) - 2, 5, 5, kP50);
    c.fill_rect(f.X(x) - 2, f.Y(p99) - 2, 5, 5, kP99);
    if (i > 0) {
      const auto& [px, pp50, pp99] = st[i - 1];
      c.line(f.X(px), f.Y(pp50), f.X(x), f.Y(p50), kP50);
      c.line(f.X(px), f.Y(pp99), f.X(x), f.Y(p99), kP99);
    }
  }
  // Legend, top right inside the plot.
  const int lx = f.px0 + f.pw - 330, ly = f.py0 + 8;
  c.fill_rect(lx, ly, 320, st.empty() ? 28 : 74, kBackground);
  c.frame_rect(lx, ly, 320, st.empty() ? 28 : 74, kInk);
  c.fill_rect(lx + 8, ly + 10, 6, 6, kPoints);
  c.text(lx + 22, ly + 6, "one estimate", kInk, kText);
  if (!st.empty()) {
    c.fill_rect(lx + 8, ly + 32, 6, 6, kP50);
    c.text(lx + 22, ly + 28, "stats p50", kInk, kText);
    c.fill_rect(lx + 8, ly + 54, 6, 6, kP99);
    c.text(lx + 22, ly + 50, "stats p99", kInk, kText);
  }
  write_png(path, c);
}
}  // namespace tipforce::map
