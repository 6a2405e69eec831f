#include "quantity.hpp"

#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <string_view>
#include <utility>

namespace tipforce::map {
namespace {
bool ends_with(const std::string& s, std::string_view suffix) {
  return s.size() >= suffix.size() && s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

std::string param_title(const std::string& name) {
  static const std::array<std::pair<const char*, const char*>, 13> kTitles{{
      {"k_n_per_m", "contact stiffness k"},
      {"h_m", "surface separation h (topography)"},
      {"c_ns_per_m", "contact damping c"},
      {"e_star_pa", "effective modulus E*"},
      {"radius_m", "tip radius R"},
      {"hamaker_j", "Hamaker constant H"},
      {"a0_m", "intermolecular distance a0"},
      {"eta_pa_s", "sample viscosity eta"},
      {"drive_amplitude_m", "drive amplitude"},
      {"drive_frequency_hz", "drive frequency"},
      {"drive_phase_rad", "drive phase"},
      {"drive_chirp_hz_per_s", "drive chirp rate"},
      {"q_factor", "quality factor"},
  }};
  for (const auto& [k, t] : kTitles)
    if (name == k) return t;
  return name;
}
}  // namespace

std::string si_unit_of_param(const std::string& name) {
  // Longest suffixes first: "_ns_per_m" before "_per_m" before "_m".
  static const std::array<std::pair<const char*, const char*>, 11> kSuffixes{{
      {"_ns_per_m", "N*s/m"},
      {"_n_per_m", "N/m"},
      {"_hz_per_s", "Hz/s"},
      {"_pa_s", "Pa*s"},
      {"_pa", "Pa"},
      {"_hz", "Hz"},
      {"_rad", "rad"},
      {"_m", "m"},
      {"_j", "J"},
      {"_n", "N"},
      {"_s", "s"},
  }};
  for (const auto& [suffix, unit] : kSuffixes)
    if (ends_with(name, suffix)) return unit;
  return "";
}

Quantity param_quantity(const std::string& name) {
  Quantity q{name, param_title(name), si_unit_of_param(name), ""};
  if (name == "h_m") {
    q.title = "height -h (topography)";
    q.note = "shown: -h (h = rest position to surface), so a raised surface is bright";
    q.display_factor = -1.0;
  }
  return q;
}

Quantity sigma_quantity(const std::string& name) {
  return {name + "_sigma", "1-sigma uncertainty of " + name, si_unit_of_param(name), ""};
}

Quantity peak_force_quantity() { return {"peak_force_n", "peak repulsive force", "N", ""}; }
Quantity mean_force_quantity() { return {"mean_force_n", "mean tip-sample force", "N", ""}; }
Quantity max_indentation_quantity() { return {"max_indentation_m", "maximum indentation", "m", ""}; }
Quantity dissipated_energy_quantity() {
  return {"dissipated_energy_j", "dissipated energy per period", "J", ""};
}
Quantity misfit_quantity() { return {"misfit", "relative L2 misfit", "", ""}; }

DisplayUnit display_unit(const std::string& si_unit, double max_abs) {
  if (si_unit.empty() || si_unit == "rad") return {1.0, si_unit};
  static const std::array<const char*, 11> kPrefixes{"a", "f", "p", "n", "u", "m", "", "k", "M", "G", "T"};
  int exp3 = 0;
  if (std::isfinite(max_abs) && max_abs > 0) {
    exp3 = static_cast<int>(std::floor(std::log10(max_abs) / 3.0));
    // 0.1 .. 1 N/m reads better as 0.5 N/m than 500 mN/m: keep one decade below 1.
    if (max_abs >= 0.1 && max_abs < 1.0) exp3 = 0;
    exp3 = std::clamp(exp3, -6, 4);  // a .. T
  }
  const int idx = exp3 + 6;
  const double factor = std::pow(10.0, -3.0 * exp3);
  return {factor, std::string(kPrefixes[static_cast<std::size_t>(idx)]) + si_unit};
}

std::string unit_suffix(const DisplayUnit& u) { return u.label.empty() ? "" : "[" + u.label + "]"; }

std::string format_number(double v, int digits) {
  if (std::isnan(v)) return "nan";
  if (std::isinf(v)) return v > 0 ? "inf" : "-inf";
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.*g", digits, v);
  std::string s = buf;
  if (s == "-0") s = "0";
  return s;
}

std::string format_us(double us) {
  if (std::isfinite(us) && std::abs(us) >= 1000.0) {
    char buf[64];
    std::snprintf(buf, sizeof buf, "%.0f", us);
    return buf;
  }
  return format_number(us, 4);
}

std::string exact_number(double v) {
  if (std::isnan(v)) return "nan";
  char buf[64];
  const auto res = std::to_chars(buf, buf + sizeof buf, v);
  return std::string(buf, res.ptr);
}
}  // namespace tipforce::map
