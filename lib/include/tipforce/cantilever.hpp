#pragma once
// Modal analysis of a rectangular clamped-free Euler-Bernoulli cantilever (SPEC section 1).
#include <string>
#include <variant>
#include <vector>

namespace tipforce {

// Geometry and material of a rectangular beam.
struct BeamGeometry {
  double length_m = 0;
  double width_m = 0;
  double thickness_m = 0;
  double youngs_modulus_pa = 0;
  double density_kg_m3 = 0;
};

// A calibrated probe: first resonance and static stiffness; higher modes follow the beam ratios.
struct CalibratedProbe {
  double f1_hz = 0;
  double k_c_n_per_m = 0;
};

enum class Sensor { displacement, optical_lever };

struct ProbeSpec {
  std::variant<BeamGeometry, CalibratedProbe> cantilever;
  std::vector<double> quality_factors{100.0};  // one for all modes, or one per mode
  int modes = 8;
  Sensor sensor = Sensor::displacement;
};

// The paper's cantilever (shared/seed/paper.tex: rectangular silicon, 525 x 35 x 5 um, E 176 GPa,
// 2330 kg/m^3, Q 100 in every mode): the reference probe of the tests, `tipforce bench` and the
// demo's configuration.
ProbeSpec paper_probe_spec(int modes = 8);

// One mode of the clamped-free beam. Shapes are normalised so that the integral of phi^2 over
// [0, L] equals L (|phi(L)| = 2).
struct Mode {
  double beta_l = 0;          // root of cos(x) cosh(x) + 1 = 0
  double omega_rad_per_s = 0;
  double frequency_hz = 0;
  double quality_factor = 0;
  double zeta = 0;            // 1 / (2 Q)
  double phi_tip = 0;         // phi(L)
  double slope_tip = 0;       // L * phi'(L): dimensionless tip slope
  double gamma = 0;           // (1/L) * integral of phi over [0, L]
};

// The cantilever's modal model: what the forward solver needs, independent of the force model.
class ModalModel {
 public:
  // Throws std::invalid_argument for non-positive or non-finite inputs, naming the field.
  explicit ModalModel(const ProbeSpec& spec);

  const std::vector<Mode>& modes() const { return modes_; }
  int n_modes() const { return static_cast<int>(modes_.size()); }
  // mu * L: the modal mass of every mode under this normalisation.
  double modal_mass_kg() const { return modal_mass_kg_; }
  // 3 E I / L^3 (or the calibrated k_c).
  double static_stiffness_n_per_m() const { return static_stiffness_n_per_m_; }
  Sensor sensor() const { return sensor_; }
  // Weight of mode i's coordinate in the measured signal: phi_i(L) for a displacement sensor,
  // L phi_i'(L) * 2/3 for an optical lever (statically calibrated against the tip deflection).
  double sensor_gain(int mode) const;

 private:
  std::vector<Mode> modes_;
  double modal_mass_kg_ = 0;
  double static_stiffness_n_per_m_ = 0;
  Sensor sensor_ = Sensor::displacement;
};

// The i-th (0-based) root of cos(x) cosh(x) + 1 = 0.
double clamped_free_root(int i);
// phi_i(x) at xi = x / L in [0, 1], in a form that cannot overflow for high modes.
double mode_shape(double beta_l, double xi);
// d phi_i / d xi at xi (= L phi_i'(x)).
double mode_shape_slope(double beta_l, double xi);

}  // namespace tipforce
