#pragma once
#include <string>

namespace tipforce::map {
// One mapped quantity: its file stem, a human title and its SI unit without prefix
// ("N/m", "m", "N*s/m", "Pa", "J", "N"; "" for dimensionless).
struct Quantity {
  std::string key;    // file stem, e.g. "k_n_per_m", "k_n_per_m_sigma", "peak_force_n"
  std::string title;  // e.g. "contact stiffness k"
  std::string si_unit;
  std::string note;   // an extra line for the image legend (may be empty)
  // What the images and .gsf files show is display_factor x the estimate: -1 for h_m, a
  // separation, so that the map is topography with a raised surface bright (AFM convention).
  double display_factor = 1.0;
};

// SI unit of a parameter from the naming convention of SPEC section 1 (suffix _n_per_m, _m, ...).
std::string si_unit_of_param(const std::string& name);
Quantity param_quantity(const std::string& name);
Quantity sigma_quantity(const std::string& name);
Quantity peak_force_quantity();
Quantity mean_force_quantity();
Quantity max_indentation_quantity();
Quantity dissipated_energy_quantity();
Quantity misfit_quantity();

// A display unit: value_in_display = value_si * factor, written with label (e.g. 1e9, "nm").
struct DisplayUnit {
  double factor = 1.0;
  std::string label;  // "" for dimensionless
};

// Chooses an SI prefix so that max_abs shows as 1..999 (a..T); "N/m" stays N/m for 0.1..999
// N/m, "m" becomes nm/um, "Pa" kPa/MPa/GPa, "J" aJ/fJ, "N*s/m" uN*s/m, "" never gets one.
DisplayUnit display_unit(const std::string& si_unit, double max_abs);

// "[nm]" style bracket ("" for dimensionless).
std::string unit_suffix(const DisplayUnit& u);

// Compact number for labels: up to `digits` significant digits, no trailing zeros, "-0" -> "0".
std::string format_number(double v, int digits = 4);

// Microseconds for summaries: whole numbers from 1000 up ("15960"), else 4 significant digits.
std::string format_us(double us);

// Shortest text that reads back to exactly v (CSV, GSF header); "nan" for NaN.
std::string exact_number(double v);
}  // namespace tipforce::map
