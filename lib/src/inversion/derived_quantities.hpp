#pragma once
// What the fit says about the contact beyond its parameters: peak and mean force, indentation
// and the energy dissipated per drive period, from the tip-sample force and tip position of the
// solve at the estimate.
#include <span>

#include "tipforce/force_model.hpp"

namespace tipforce::inversion {

struct DerivedQuantities {
  double peak_force_n = 0;         // largest repulsive magnitude
  double mean_force_n = 0;         // time average
  double max_indentation_m = 0;
  double dissipated_energy_j = 0;  // per drive period
};

// force_n and tip_z_m per sample (sample period dt); drive_hz the drive frequency (0: none, then
// the work over the whole window is reported).
DerivedQuantities derived_quantities(ForceModelKind model, const ForceParams& params, std::span<const double> force_n,
                                     std::span<const double> tip_z_m, double drive_hz, double sample_period_s);

}  // namespace tipforce::inversion
