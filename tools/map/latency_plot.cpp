#include "latency_plot.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <tuple>
#include <utility>

#include "figure.hpp"
#include "tipforce/percentile.hpp"
#include "plot_frame.hpp"
#include "quantity.hpp"
#include "ticks.hpp"

namespace tipforce::map {
namespace {
constexpr double kTitle = 16, kText = 13;
constexpr int kW = 900, kH = 560;
constexpr int kLeft = 110, kRight = 40, kTop = 60, kBottom = 70;
constexpr Rgb kPoints{49, 104, 142};   // viridis blue
constexpr Rgb kP50{53, 183, 121};      // viridis green
constexpr Rgb kP99{215, 48, 39};

struct Frame : PlotFrame {
  Frame() {
    px0 = kLeft;
    py0 = kTop;
    pw = kW - kLeft - kRight;
    ph = kH - kTop - kBottom;
  }
};

void draw_frame(Painter& p, const Frame& f, const std::string& title, const std::string& xlabel,
                const std::string& ylabel) {
  draw_plot_frame(p, f, title, xlabel, ylabel);
}

std::vector<double> latencies(const std::vector<tipforce::force_estimate_t>& estimates) {
  std::vector<double> out;
  for (const auto& e : estimates)
    if (e.receive_utime != 0 && e.publish_utime != 0) out.push_back(static_cast<double>(e.publish_utime - e.receive_utime));
  return out;
}
}  // namespace

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
  const double width_us = (hi - lo) / bins;
  std::vector<std::size_t> counts(static_cast<std::size_t>(bins), 0);
  for (double v : lat) {
    const int b = std::clamp(static_cast<int>((v - lo) / width_us), 0, bins - 1);
    ++counts[static_cast<std::size_t>(b)];
  }
  const double max_count = static_cast<double>(*std::max_element(counts.begin(), counts.end()));

  Frame f;
  f.x = nice_axis(lo, hi, false);
  f.y = nice_axis(0, max_count, true);
  const std::string title = "receive -> publish latency: " + std::to_string(s.n) + " estimates, p50 " +
                            format_us(s.p50_us) + " us, p99 " + format_us(s.p99_us) + " us";
  const int width = std::max(kW, 32 + static_cast<int>(measure_text(title, kTitle, true).width));
  write_figure(path, width, kH, [&](Painter& p) {
    draw_frame(p, f, title, "latency [us]", "estimates per bin");
    for (int b = 0; b < bins; ++b) {
      if (counts[static_cast<std::size_t>(b)] == 0) continue;
      const double b0 = lo + width_us * b, b1 = b0 + width_us;
      const double x0 = f.X(b0), x1 = f.X(b1);
      const double y0 = f.Y(static_cast<double>(counts[static_cast<std::size_t>(b)])), y1 = f.Y(0);
      p.fill_rect(x0, y0, x1 - x0, y1 - y0, kPoints);
      p.frame_rect(x0, y0, x1 - x0, y1 - y0, kInk, 0.5);
    }
    struct Marker {
      double v;
      Rgb colour;
      const char* name;
      int dy;
    };
    for (const Marker& m : {Marker{s.p50_us, kP50, "p50", 4}, Marker{s.p99_us, kP99, "p99", 24}}) {
      const double x = f.X(m.v);
      for (double y = f.py0; y < f.py0 + f.ph; y += 6) p.line(x, y, x, std::min(y + 3.0, double(f.py0 + f.ph)), m.colour, 1.5);
      p.text(x + 4, f.py0 + m.dy, m.name, kText, Align::left, m.colour, true);
    }
  });
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
  write_figure(path, kW, kH, [&](Painter& p) {
    draw_frame(p, f, "latency over time (" + std::to_string(pts.size()) + " estimates)", "time since first receive [s]",
               "receive -> publish latency [us]");
    p.clip(f.px0, f.py0, f.pw, f.ph);
    for (const auto& [x, y] : pts) p.dot(f.X(x), f.Y(y), 1.6, kPoints);
    std::vector<std::pair<double, double>> l50, l99;
    for (const auto& [x, p50, p99] : st) {
      l50.emplace_back(f.X(x), f.Y(p50));
      l99.emplace_back(f.X(x), f.Y(p99));
    }
    p.polyline(l50, kP50, 1.5);
    p.polyline(l99, kP99, 1.5);
    for (std::size_t i = 0; i < st.size(); ++i) {
      p.dot(l50[i].first, l50[i].second, 2.5, kP50);
      p.dot(l99[i].first, l99[i].second, 2.5, kP99);
    }
    p.unclip();
    // Legend, top right inside the plot.
    const double lx = f.px0 + f.pw - 180, ly = f.py0 + 8, lh = st.empty() ? 26 : 66;
    p.fill_rect(lx, ly, 170, lh, kBackground);
    p.frame_rect(lx, ly, 170, lh, kInk);
    p.dot(lx + 12, ly + 13, 2.5, kPoints);
    p.text(lx + 24, ly + 5, "one estimate", kText);
    if (!st.empty()) {
      p.dot(lx + 12, ly + 33, 3, kP50);
      p.text(lx + 24, ly + 25, "stats p50", kText);
      p.dot(lx + 12, ly + 53, 3, kP99);
      p.text(lx + 24, ly + 45, "stats p99", kText);
    }
  });
}
}  // namespace tipforce::map
