// The files of `tipforce inspect`: four figures (PNG and PDF, through tools/map's Cairo figures)
// and the CSV of the curves, the landscape and the estimate.
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>

#include "colormap.hpp"
#include "figure.hpp"
#include "inspect_run.hpp"
#include "map_grid.hpp"
#include "plot_frame.hpp"
#include "quantity.hpp"
#include "ticks.hpp"

namespace tipforce::inspect {
namespace {
using namespace tipforce::map;
namespace fs = std::filesystem;

constexpr int kW = 900, kH = 560;
constexpr Rgb kMeasured{120, 120, 120};
constexpr Rgb kFitted{49, 104, 142};
constexpr Rgb kResidual{215, 48, 39};
constexpr Rgb kForce{53, 120, 60};

PlotFrame frame(double xlo, double xhi, double ylo, double yhi, int top, int height) {
  PlotFrame f;
  f.px0 = 120;
  f.py0 = top;
  f.pw = kW - 120 - 40;
  f.ph = height;
  f.x = nice_axis(xlo, xhi, false);
  f.y = nice_axis(ylo, yhi, false);
  return f;
}

std::pair<double, double> span(const std::vector<double>& v, double factor) {
  double lo = INFINITY, hi = -INFINITY;
  for (double x : v)
    if (std::isfinite(x)) lo = std::min(lo, x * factor), hi = std::max(hi, x * factor);
  return {lo, hi};
}

std::vector<std::pair<double, double>> points(const PlotFrame& f, const std::vector<double>& x, double fx,
                                              const std::vector<double>& y, double fy) {
  std::vector<std::pair<double, double>> p;
  for (std::size_t i = 0; i < x.size(); ++i) p.emplace_back(f.X(x[i] * fx), f.Y(y[i] * fy));
  return p;
}

void legend(Painter& p, double x, double y, const std::vector<std::pair<Rgb, std::string>>& entries) {
  p.fill_rect(x, y, 190, 8 + 20.0 * entries.size(), kBackground);
  p.frame_rect(x, y, 190, 8 + 20.0 * entries.size(), kInk);
  for (std::size_t i = 0; i < entries.size(); ++i) {
    p.line(x + 8, y + 14 + 20.0 * i, x + 30, y + 14 + 20.0 * i, entries[i].first, 2);
    p.text(x + 38, y + 5 + 20.0 * i, entries[i].second, 13);
  }
}

void write_csv(const InspectOptions& o, InspectReport& r) {
  auto path = [&](const char* n) { return (fs::path(o.out) / n).string(); };
  {
    std::ofstream f(path("curves.csv"));
    f.precision(17);
    f << "t_s,measured_m,fitted_m,residual_m,force_n,tip_z_m\n";
    const Curves& c = r.curves;
    for (std::size_t i = 0; i < c.t_s.size(); ++i)
      f << c.t_s[i] << ',' << c.measured_m[i] << ',' << c.fitted_m[i] << ',' << c.residual_m[i] << ',' << c.force_n[i]
        << ',' << c.tip_z_m[i] << '\n';
    if (!f) throw InspectError("cannot write " + path("curves.csv"));
  }
  {
    std::ofstream f(path("estimate.csv"));
    f.precision(17);
    f << "name,value,sigma,source\n";
    for (std::size_t i = 0; i < r.names.size(); ++i) f << r.names[i] << ',' << r.values[i] << ',' << r.sigma[i] << ',' << r.source << '\n';
    f << "misfit_reported," << r.estimate_misfit << ",," << r.source << "\nmisfit_curve," << r.curve_misfit << ",,curves.csv\n";
    // The modal state the curves start from, so that anyone can simulate them again.
    for (std::size_t i = 0; i < r.start_q.size(); ++i)
      f << "start_q_mode" << i + 1 << "," << r.start_q[i] << ",,curves.csv\nstart_v_mode" << i + 1 << "," << r.start_v[i]
        << ",,curves.csv\n";
    if (!f) throw InspectError("cannot write " + path("estimate.csv"));
  }
  if (!r.landscape.misfit.empty()) {
    std::ofstream f(path("landscape.csv"));
    f.precision(17);
    const Landscape& L = r.landscape;
    f << L.x_name << ',' << (L.two_d ? L.y_name + "," : "") << "misfit\n";
    for (std::size_t iy = 0; iy < L.y.size(); ++iy)
      for (std::size_t ix = 0; ix < L.x.size(); ++ix) {
        f << L.x[ix] << ',';
        if (L.two_d) f << L.y[iy] << ',';
        f << L.misfit[iy * L.x.size() + ix] << '\n';
      }
    if (!f) throw InspectError("cannot write " + path("landscape.csv"));
  }
  for (const char* n : {"curves.csv", "estimate.csv", "landscape.csv"})
    if (fs::exists(path(n))) r.files.push_back(n);
}

std::string pixel_title(const InspectOptions& o, const InspectReport& r) {
  return "pixel " + std::to_string(o.pixel_x) + "," + std::to_string(o.pixel_y) + " (probe " + r.probe + ", " + r.model + ")";
}

}  // namespace

void prepare_output_dir(const InspectOptions& o) {
  std::error_code ec;
  if (fs::exists(o.out, ec) && !fs::is_directory(o.out, ec))
    throw InspectError("--out " + o.out + " exists and is not a directory");
  fs::create_directories(o.out, ec);
  if (ec || !fs::is_directory(o.out, ec))
    throw InspectError("--out: cannot create output directory " + o.out + (ec ? ": " + ec.message() : ""));
  // Permission bits do not tell (root ignores them, a read-only mount does not show in them):
  // a file is created there and removed.
  const fs::path probe = fs::path(o.out) / (".tipforce-inspect-write-test-" + std::to_string(::getpid()));
  {
    std::ofstream f(probe);
    if (!f || !(f << "x") || !f.flush()) {
      fs::remove(probe, ec);
      throw InspectError("--out: cannot write in " + o.out);
    }
  }
  fs::remove(probe, ec);
}

void write_inspect_files(const InspectOptions& o, InspectReport& r) {
  prepare_output_dir(o);
  write_csv(o, r);
  auto add = [&](const std::string& stem) {
    r.files.push_back(stem + ".png");
    r.files.push_back(stem + ".pdf");
    return (fs::path(o.out) / (stem + ".png")).string();
  };
  const Curves& c = r.curves;
  const double t0 = c.t_s.empty() ? 0 : c.t_s.front();
  std::vector<double> t_us;
  for (double t : c.t_s) t_us.push_back((t - t0) * 1e6);

  // 1. measured against fitted deflection, the residual below.
  {
    auto [lo, hi] = span(c.measured_m, 1e9);
    auto [flo, fhi] = span(c.fitted_m, 1e9);
    const PlotFrame top = frame(0, t_us.back(), std::min(lo, flo), std::max(hi, fhi), 60, 300);
    auto [rlo, rhi] = span(c.residual_m, 1e9);
    const double rm = std::max({std::abs(rlo), std::abs(rhi), 1e-6});
    const PlotFrame bottom = frame(0, t_us.back(), -rm, rm, 410, 100);
    char misfit[160];
    std::snprintf(misfit, sizeof misfit, "misfit %.3g (reported %.3g)", r.curve_misfit, r.estimate_misfit);
    write_figure(add("deflection"), kW, 570, [&](Painter& p) {
      draw_plot_frame(p, top, "measured and fitted deflection, " + pixel_title(o, r), "", "deflection [nm]");
      p.clip(top.px0, top.py0, top.pw, top.ph);
      p.polyline(points(top, t_us, 1, c.measured_m, 1e9), kMeasured, 1.0);
      p.polyline(points(top, t_us, 1, c.fitted_m, 1e9), kFitted, 1.6);
      p.unclip();
      legend(p, top.px0 + top.pw - 200, top.py0 + 8, {{kMeasured, "measured"}, {kFitted, "fitted"}});
      p.text(top.px0, top.py0 - 20, misfit, 13);
      draw_plot_frame(p, bottom, "", "time from the window's first sample [\u00b5s]", "residual [nm]");
      p.clip(bottom.px0, bottom.py0, bottom.pw, bottom.ph);
      p.polyline(points(bottom, t_us, 1, c.residual_m, 1e9), kResidual, 1.0);
      p.unclip();
    });
  }
  // 2. force against time.
  {
    auto [lo, hi] = span(c.force_n, 1e9);
    const PlotFrame f = frame(0, t_us.back(), std::min(lo, 0.0), std::max(hi, 0.0), 60, 420);
    write_figure(add("force_time"), kW, kH, [&](Painter& p) {
      draw_plot_frame(p, f, "tip-sample force (positive toward the sample), " + pixel_title(o, r),
                      "time from the window's first sample [\u00b5s]", "force [nN]");
      p.clip(f.px0, f.py0, f.pw, f.ph);
      p.polyline(points(f, t_us, 1, c.force_n, 1e9), kForce, 1.5);
      p.unclip();
    });
  }
  // 3. force against tip position: the force-distance curve, distance from the surface.
  {
    const double h = std::isfinite(r.h_m) ? r.h_m : 0.0;
    std::vector<double> d;
    for (double z : c.tip_z_m) d.push_back(z - h);
    auto [dlo, dhi] = span(d, 1e9);
    auto [flo, fhi] = span(c.force_n, 1e9);
    const PlotFrame f = frame(dlo, dhi, std::min(flo, 0.0), std::max(fhi, 0.0), 60, 420);
    const std::string xl = std::isfinite(r.h_m) ? "tip position z - h [nm] (0: the surface, positive: in contact)"
                                                 : "tip position z [nm]";
    write_figure(add("force_distance"), kW, kH, [&](Painter& p) {
      draw_plot_frame(p, f, "force against tip position, " + pixel_title(o, r), xl, "force [nN]");
      p.clip(f.px0, f.py0, f.pw, f.ph);
      for (std::size_t i = 0; i < d.size(); ++i) p.dot(f.X(d[i] * 1e9), f.Y(c.force_n[i] * 1e9), 1.8, kForce);
      p.unclip();
    });
  }
  // 4. the misfit landscape with the estimate and its 2-sigma ellipse.
  const Landscape& L = r.landscape;
  if (!L.misfit.empty()) {
    const DisplayUnit ux = display_unit(si_unit_of_param(L.x_name), std::max(std::abs(L.x.front()), std::abs(L.x.back())));
    const std::string xl = L.x_name + (ux.label.empty() ? "" : " [" + ux.label + "]");
    if (!L.two_d) {
      auto [mlo, mhi] = span(L.misfit, 1);
      std::vector<double> xs;
      for (double x : L.x) xs.push_back(x * ux.factor);
      const PlotFrame f = frame(xs.front(), xs.back(), 0, mhi, 60, 420);
      write_figure(add("misfit_landscape"), kW, kH, [&](Painter& p) {
        draw_plot_frame(p, f, "misfit over " + L.x_name + ", " + pixel_title(o, r), xl, "relative misfit");
        p.polyline(points(f, xs, 1, L.misfit, 1), kFitted, 1.6);
        for (double k : {-2.0, 0.0, 2.0}) {
          const double x = f.X((L.x_est + k * L.sx) * ux.factor);
          p.line(x, f.py0, x, f.py0 + f.ph, k == 0 ? kInk : kResidual, k == 0 ? 1.5 : 1.0);
        }
      });
    } else {
      const DisplayUnit uy = display_unit(si_unit_of_param(L.y_name), std::max(std::abs(L.y.front()), std::abs(L.y.back())));
      const std::string yl = L.y_name + (uy.label.empty() ? "" : " [" + uy.label + "]");
      PlotFrame f;
      f.px0 = 120;
      f.py0 = 60;
      f.pw = 420;
      f.ph = 420;
      f.x = {L.x.front() * ux.factor, L.x.back() * ux.factor, round_ticks(L.x.front() * ux.factor, L.x.back() * ux.factor, 5).values};
      f.y = {L.y.front() * uy.factor, L.y.back() * uy.factor, round_ticks(L.y.front() * uy.factor, L.y.back() * uy.factor, 5).values};
      // log10 of the misfit: the valley's floor and its walls both stay visible.
      Grid g(static_cast<int>(L.x.size()), static_cast<int>(L.y.size()));
      for (std::size_t iy = 0; iy < L.y.size(); ++iy)
        for (std::size_t ix = 0; ix < L.x.size(); ++ix)  // row 0 at the top: the largest y
          g.at(static_cast<int>(ix), static_cast<int>(L.y.size() - 1 - iy)) = std::log10(L.misfit[iy * L.x.size() + ix]);
      const ValueRange range = value_range(g);
      const int cell = std::max(1, 420 / static_cast<int>(L.x.size()));
      f.pw = cell * static_cast<int>(L.x.size());
      f.ph = cell * static_cast<int>(L.y.size());
      Raster heat(f.pw, f.ph);
      for (int y = 0; y < g.height; ++y)
        for (int x = 0; x < g.width; ++x) heat.fill(x * cell, y * cell, cell, cell, colour_of(g.at(x, y), range.lo, range.hi));
      // The 2-sigma ellipse of the covariance [sx^2, rho sx sy; rho sx sy, sy^2].
      std::vector<std::pair<double, double>> ellipse;
      const double s = std::sqrt(std::max(0.0, 1 - L.rho * L.rho));
      for (int k = 0; k <= 96; ++k) {
        const double a = 2 * M_PI * k / 96;
        const double ex = L.x_est + 2 * L.sx * std::cos(a);
        const double ey = L.y_est + 2 * L.sy * (L.rho * std::cos(a) + s * std::sin(a));
        // Grid cells are centred on the grid values: place the ellipse on the same scale.
        const double fx = (ex - L.x.front()) / (L.x.back() - L.x.front());
        const double fy = (ey - L.y.front()) / (L.y.back() - L.y.front());
        ellipse.emplace_back(f.px0 + cell * (0.5 + fx * (L.x.size() - 1)), f.py0 + f.ph - cell * (0.5 + fy * (L.y.size() - 1)));
      }
      const double ex = f.px0 + cell * (0.5 + (L.x_est - L.x.front()) / (L.x.back() - L.x.front()) * (L.x.size() - 1));
      const double ey = f.py0 + f.ph - cell * (0.5 + (L.y_est - L.y.front()) / (L.y.back() - L.y.front()) * (L.y.size() - 1));
      char corr[96];
      std::snprintf(corr, sizeof corr, "correlation %.3f", L.rho);
      write_figure(add("misfit_landscape"), kW + 60, kH, [&](Painter& p) {
        p.image(f.px0, f.py0, heat);
        draw_plot_frame(p, PlotFrame{f.x, f.y, f.px0, f.py0, f.pw, f.ph},
                        "misfit landscape (colour: log10 relative misfit), " + pixel_title(o, r), xl, yl);
        p.clip(f.px0, f.py0, f.pw, f.ph);
        p.polyline(ellipse, kBackground, 2.5);
        p.polyline(ellipse, kResidual, 1.5);
        p.line(ex - 7, ey, ex + 7, ey, kBackground, 3);
        p.line(ex, ey - 7, ex, ey + 7, kBackground, 3);
        p.line(ex - 7, ey, ex + 7, ey, kInk, 1.5);
        p.line(ex, ey - 7, ex, ey + 7, kInk, 1.5);
        p.unclip();
        const double bx = f.px0 + f.pw + 40;
        Raster bar(20, f.ph);
        for (int row = 0; row < f.ph; ++row)
          bar.fill(0, row, 20, 1, viridis()[static_cast<std::size_t>(std::lround(255.0 * (f.ph - 1 - row) / std::max(1, f.ph - 1)))]);
        p.image(static_cast<int>(bx), f.py0, bar);
        p.frame_rect(bx, f.py0, 20, f.ph, kInk);
        for (double t : round_ticks(range.lo, range.hi, 5).values) {
          const double y = f.py0 + f.ph - (t - range.lo) / (range.hi - range.lo) * f.ph;
          p.line(bx + 20, y, bx + 25, y, kInk);
          p.text(bx + 28, y - 8, format_number(t, 3), 12);
        }
        p.text(bx + 60, f.py0 + 10, "+  the estimate", 13);
        p.text(bx + 60, f.py0 + 30, "red: its 2-sigma ellipse", 13);
        p.text(bx + 60, f.py0 + 60, corr, 13);
        p.text(bx + 60, f.py0 + 80, "the other unknowns and the start", 13);
        p.text(bx + 60, f.py0 + 100, "state held at the estimate's", 13);
      });
    }
  }
}

}  // namespace tipforce::inspect
