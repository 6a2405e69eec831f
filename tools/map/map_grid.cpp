#include "map_grid.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "tipforce/percentile.hpp"
#include "map_error.hpp"

namespace tipforce::map {
namespace {
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr long long kMaxPixels = 64LL * 1024 * 1024;

double finite_or_nan(double v) { return std::isfinite(v) ? v : kNaN; }
}  // namespace

Grid::Grid(int w, int h)
    : width(w), height(h), v(static_cast<std::size_t>(w) * static_cast<std::size_t>(h), kNaN) {}

ValueRange value_range(const std::vector<const Grid*>& grids) {
  ValueRange r;
  std::vector<double> finite;
  for (const Grid* g : grids)
    for (double x : g->v)
      if (std::isfinite(x)) finite.push_back(x);
  r.valid = finite.size();
  if (finite.empty()) return r;  // any = false, lo..hi = 0..1
  r.any = true;
  std::sort(finite.begin(), finite.end());
  r.data_min = finite.front();
  r.data_max = finite.back();
  if (r.data_max == r.data_min) {
    r.constant = true;
    const double half = r.data_min != 0.0 ? std::abs(r.data_min) * 1e-6 : 1e-30;
    r.lo = r.data_min - half;
    r.hi = r.data_min + half;
    return r;
  }
  const double p1 = percentile(finite, 0.01), p99 = percentile(finite, 0.99);
  const double span = p99 - p1;
  // The extreme values within reach of the percentiles: only what lies beyond is clipped.
  r.lo = *std::lower_bound(finite.begin(), finite.end(), p1 - kRangeReach * span);
  r.hi = *(std::upper_bound(finite.begin(), finite.end(), p99 + kRangeReach * span) - 1);
  for (double x : finite) {
    if (x < r.lo) ++r.below;
    if (x > r.hi) ++r.above;
  }
  return r;
}

Grid scaled(const Grid& g, double factor) {
  Grid out = g;
  for (double& x : out.v) x *= factor;
  return out;
}

ValueRange value_range(const Grid& g) { return value_range(std::vector<const Grid*>{&g}); }

double param_value(const tipforce::force_estimate_t& e, const std::string& name, bool sigma) {
  const std::size_t n = std::min({static_cast<std::size_t>(std::max(e.n_params, 0)), e.param_names.size(),
                                  e.params.size(), e.param_sigma.size()});
  for (std::size_t i = 0; i < n; ++i)
    if (e.param_names[i] == name) return finite_or_nan(sigma ? e.param_sigma[i] : e.params[i]);
  return kNaN;
}

MapSet build_maps(const std::vector<tipforce::force_estimate_t>& estimates, int scan_width, int scan_height) {
  MapSet ms;
  int max_x = -1, max_y = -1;
  for (const auto& e : estimates) {
    if (e.pixel_x < 0 || e.pixel_y < 0) {
      ++ms.negative_pixels;
      continue;
    }
    max_x = std::max(max_x, e.pixel_x);
    max_y = std::max(max_y, e.pixel_y);
  }
  if (max_x < 0) throw MapError("no estimate has a valid pixel (pixel_x, pixel_y >= 0)");
  const long long w = std::max<long long>(static_cast<long long>(max_x) + 1, scan_width),
                  h = std::max<long long>(static_cast<long long>(max_y) + 1, scan_height);
  if (w * h > kMaxPixels)
    throw MapError("the map would be " + std::to_string(w) + " x " + std::to_string(h) +
                   " pixels (largest pixel_x " + std::to_string(max_x) + ", pixel_y " + std::to_string(max_y) +
                   "); refusing more than 64 Mpixel");
  ms.width = static_cast<int>(w);
  ms.height = static_cast<int>(h);
  ms.estimate_index.assign(static_cast<std::size_t>(w * h), -1);

  for (std::size_t i = 0; i < estimates.size(); ++i) {
    const auto& e = estimates[i];
    if (e.pixel_x < 0 || e.pixel_y < 0) continue;
    auto& slot = ms.estimate_index[static_cast<std::size_t>(e.pixel_y) * static_cast<std::size_t>(w) +
                                   static_cast<std::size_t>(e.pixel_x)];
    if (slot >= 0) ++ms.duplicates;  // the later estimate of a pixel wins
    slot = static_cast<int>(i);
    const std::size_t n = std::min({static_cast<std::size_t>(std::max(e.n_params, 0)), e.param_names.size()});
    for (std::size_t k = 0; k < n; ++k)
      if (std::find(ms.param_names.begin(), ms.param_names.end(), e.param_names[k]) == ms.param_names.end())
        ms.param_names.push_back(e.param_names[k]);
  }

  // One grid per quantity; a rejected window has no estimate of anything.
  struct Spec {
    Quantity q;
    std::string param;
    bool sigma;
    double tipforce::force_estimate_t::*field;
  };
  std::vector<Spec> specs;
  for (const auto& p : ms.param_names) specs.push_back({param_quantity(p), p, false, nullptr});
  for (const auto& p : ms.param_names) specs.push_back({sigma_quantity(p), p, true, nullptr});
  specs.push_back({peak_force_quantity(), "", false, &tipforce::force_estimate_t::peak_force_n});
  specs.push_back({mean_force_quantity(), "", false, &tipforce::force_estimate_t::mean_force_n});
  specs.push_back({max_indentation_quantity(), "", false, &tipforce::force_estimate_t::max_indentation_m});
  specs.push_back({dissipated_energy_quantity(), "", false, &tipforce::force_estimate_t::dissipated_energy_j});
  specs.push_back({misfit_quantity(), "", false, &tipforce::force_estimate_t::misfit});

  ms.status = Grid(ms.width, ms.height);
  for (const auto& s : specs) ms.maps.push_back({s.q, Grid(ms.width, ms.height)});
  for (int y = 0; y < ms.height; ++y)
    for (int x = 0; x < ms.width; ++x) {
      const int idx = ms.estimate_index[static_cast<std::size_t>(y) * static_cast<std::size_t>(w) + static_cast<std::size_t>(x)];
      if (idx < 0) {
        ms.missing.emplace_back(x, y);
        continue;
      }
      const auto& e = estimates[static_cast<std::size_t>(idx)];
      ms.status.at(x, y) = e.status;
      // A rejected window (or an unknown status code) carries no estimate of anything.
      if (e.status != tipforce::force_estimate_t::STATUS_OK &&
          e.status != tipforce::force_estimate_t::STATUS_NOT_CONVERGED) {
        ms.rejected.emplace_back(x, y);
        continue;
      }
      for (std::size_t k = 0; k < specs.size(); ++k) {
        const auto& s = specs[k];
        ms.maps[k].grid.at(x, y) = s.field ? finite_or_nan(e.*(s.field)) : param_value(e, s.param, s.sigma);
      }
    }
  return ms;
}
}  // namespace tipforce::map
