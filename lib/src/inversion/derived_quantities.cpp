#include "inversion/derived_quantities.hpp"

#include <algorithm>
#include <cmath>

namespace tipforce::inversion {

DerivedQuantities derived_quantities(ForceModelKind model, const ForceParams& fp, std::span<const double> force_n,
                                     std::span<const double> tip_z_m, double drive_hz, double sample_period_s) {
  const int N = static_cast<int>(force_n.size());
  DerivedQuantities d;
  double peak = 0, mean = 0, indent = 0;
  for (int n = 0; n < N; ++n) {
    const double f = force_n[n];
    peak = std::max(peak, -f);
    mean += f;
    indent = std::max(indent, indentation_m(model, fp, tip_z_m[n]));
  }
  d.peak_force_n = peak;
  d.mean_force_n = mean / N;
  d.max_indentation_m = indent;
  // Work taken by the tip-sample force over the last whole number of drive periods, per period:
  // over whole periods the elastic part returns what it stored and only the dissipated part
  // stays (over a window cut mid-contact, stored energy would masquerade as dissipation).
  const double period_samples = drive_hz > 0 ? 1.0 / (drive_hz * sample_period_s) : 0.0;
  const int periods = period_samples > 0 ? static_cast<int>((N - 1) / period_samples) : 0;
  const int first = periods > 0 ? N - 1 - static_cast<int>(std::lround(periods * period_samples)) : 0;
  double work = 0;
  for (int n = std::max(first, 0); n + 1 < N; ++n)
    work -= 0.5 * (force_n[n] + force_n[n + 1]) * (tip_z_m[n + 1] - tip_z_m[n]);
  d.dissipated_energy_j = periods > 0 ? work / periods : work;
  return d;
}

}  // namespace tipforce::inversion
