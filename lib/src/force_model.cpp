#include "tipforce/force_model.hpp"

#include <algorithm>
#include <array>
#include <cmath>

#include "tipforce/assert.hpp"

namespace tipforce {
namespace {
constexpr std::string_view kNone[] = {"_"};
constexpr std::string_view kSpring[] = {"k_n_per_m", "h_m"};
constexpr std::string_view kKelvinVoigt[] = {"k_n_per_m", "c_ns_per_m", "h_m"};
constexpr std::string_view kHertz[] = {"e_star_pa", "radius_m", "h_m"};
constexpr std::string_view kDmt[] = {"e_star_pa", "radius_m", "hamaker_j", "a0_m", "h_m"};
constexpr std::string_view kDmtViscous[] = {"e_star_pa", "radius_m", "hamaker_j", "a0_m", "h_m", "eta_pa_s"};
}  // namespace

std::string_view to_string(ForceModelKind kind) {
  switch (kind) {
    case ForceModelKind::none: return "none";
    case ForceModelKind::spring: return "spring";
    case ForceModelKind::kelvin_voigt: return "kelvin_voigt";
    case ForceModelKind::hertz: return "hertz";
    case ForceModelKind::dmt: return "dmt";
    case ForceModelKind::dmt_viscous: return "dmt_viscous";
  }
  return "?";
}

std::optional<ForceModelKind> force_model_from_string(std::string_view name) {
  for (auto k : {ForceModelKind::none, ForceModelKind::spring, ForceModelKind::kelvin_voigt, ForceModelKind::hertz,
                 ForceModelKind::dmt, ForceModelKind::dmt_viscous})
    if (to_string(k) == name) return k;
  return std::nullopt;
}

std::span<const std::string_view> force_model_parameters(ForceModelKind kind) {
  switch (kind) {
    case ForceModelKind::none: return std::span<const std::string_view>(kNone, 0);
    case ForceModelKind::spring: return kSpring;
    case ForceModelKind::kelvin_voigt: return kKelvinVoigt;
    case ForceModelKind::hertz: return kHertz;
    case ForceModelKind::dmt: return kDmt;
    case ForceModelKind::dmt_viscous: return kDmtViscous;
  }
  return {};
}

ForceParams force_params_from(ForceModelKind kind, std::span<const double> v) {
  ForceParams p;
  const auto names = force_model_parameters(kind);
  TIPFORCE_THROW_UNLESS(v.size() >= names.size(), "too few parameter values for the model");
  for (std::size_t i = 0; i < names.size(); ++i) {
    const auto n = names[i];
    double* dst = n == "k_n_per_m"    ? &p.k_n_per_m
                  : n == "c_ns_per_m" ? &p.c_ns_per_m
                  : n == "h_m"        ? &p.h_m
                  : n == "e_star_pa"  ? &p.e_star_pa
                  : n == "radius_m"   ? &p.radius_m
                  : n == "hamaker_j"  ? &p.hamaker_j
                  : n == "a0_m"       ? &p.a0_m
                                      : &p.eta_pa_s;
    *dst = v[i];
  }
  return p;
}

double tip_sample_force_n(ForceModelKind kind, const ForceParams& p, double z, double zdot) {
  const double delta = z - p.h_m;
  switch (kind) {
    case ForceModelKind::none: return 0.0;
    case ForceModelKind::spring: return delta > 0 ? -p.k_n_per_m * delta : 0.0;
    case ForceModelKind::kelvin_voigt:
      return delta > 0 ? std::min(0.0, -p.k_n_per_m * delta - p.c_ns_per_m * zdot) : 0.0;
    case ForceModelKind::hertz:
      return delta > 0 ? -(4.0 / 3.0) * p.e_star_pa * std::sqrt(p.radius_m) * std::pow(delta, 1.5) : 0.0;
    case ForceModelKind::dmt:
    case ForceModelKind::dmt_viscous: {
      const double d = p.h_m - z;
      const double hr6 = p.hamaker_j * p.radius_m / 6.0;
      if (d > p.a0_m) return hr6 / (d * d);
      const double pen = p.a0_m - d;
      double f = hr6 / (p.a0_m * p.a0_m) - (4.0 / 3.0) * p.e_star_pa * std::sqrt(p.radius_m) * std::pow(pen, 1.5);
      if (kind == ForceModelKind::dmt_viscous) f -= p.eta_pa_s * std::sqrt(p.radius_m * pen) * zdot;
      return f;
    }
  }
  return 0.0;
}

double indentation_m(ForceModelKind kind, const ForceParams& p, double z) {
  switch (kind) {
    case ForceModelKind::none: return 0.0;
    case ForceModelKind::dmt:
    case ForceModelKind::dmt_viscous: return std::max(0.0, p.a0_m - (p.h_m - z));
    default: return std::max(0.0, z - p.h_m);
  }
}

}  // namespace tipforce
