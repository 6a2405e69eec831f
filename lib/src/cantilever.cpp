#include "tipforce/cantilever.hpp"

#include <cmath>
#include <numbers>
#include <string>

#include "tipforce/assert.hpp"
#include "quadrature.hpp"

namespace tipforce {
namespace {

void require_positive(double value, const char* name) {
  TIPFORCE_THROW_UNLESS(std::isfinite(value) && value > 0,
                        std::string(name) + " must be positive and finite, got " + std::to_string(value));
}

// The clamped-free shape cosh x - cos x - s (sinh x - sin x), s = (cosh b + cos b)/(sinh b + sin b),
// rewritten with every exponential divided by e^b so that nothing overflows for high modes.
struct ShapeTerms {
  double grow;   // coefficient of e^(x - b)
  double decay;  // coefficient of e^(-x)
  double sigma;
};
ShapeTerms shape_terms(double b) {
  const double e = std::exp(-b);
  const double denom = 1.0 - e * e + 2.0 * std::sin(b) * e;  // (sinh b + sin b) * 2 e^-b
  const double sigma = (1.0 + e * e + 2.0 * std::cos(b) * e) / denom;
  return {(std::sin(b) - std::cos(b) - e) / denom, 0.5 * (1.0 + sigma), sigma};
}

}  // namespace

double clamped_free_root(int i) {
  TIPFORCE_THROW_UNLESS(i >= 0 && i < 200, "mode index must be in [0, 200)");
  // g(x) = cos x + 1/cosh x has exactly one root in [i pi, (i+1) pi], where it changes sign.
  auto g = [](long double x) { return std::cos(x) + 1.0L / std::cosh(x); };
  long double lo = i * std::numbers::pi_v<long double>, hi = (i + 1) * std::numbers::pi_v<long double>;
  if (i == 0) lo = 1.0L;
  long double glo = g(lo);
  for (int it = 0; it < 200 && hi - lo > 1e-18L * hi; ++it) {
    const long double mid = 0.5L * (lo + hi);
    const long double gm = g(mid);
    if ((gm > 0) == (glo > 0)) {
      lo = mid;
      glo = gm;
    } else {
      hi = mid;
    }
  }
  return static_cast<double>(0.5L * (lo + hi));
}

double mode_shape(double b, double xi) {
  const ShapeTerms t = shape_terms(b);
  const double x = b * xi;
  return t.grow * std::exp(x - b) + t.decay * std::exp(-x) - std::cos(x) + t.sigma * std::sin(x);
}

double mode_shape_slope(double b, double xi) {
  const ShapeTerms t = shape_terms(b);
  const double x = b * xi;
  return b * (t.grow * std::exp(x - b) - t.decay * std::exp(-x) + std::sin(x) + t.sigma * std::cos(x));
}

ModalModel::ModalModel(const ProbeSpec& spec) : sensor_(spec.sensor) {
  TIPFORCE_THROW_UNLESS(spec.modes >= 1 && spec.modes <= 32, "modes must be in [1, 32], got " + std::to_string(spec.modes));
  TIPFORCE_THROW_UNLESS(spec.quality_factors.size() == 1 || static_cast<int>(spec.quality_factors.size()) == spec.modes,
                        "quality_factor must be one number or one per mode (" + std::to_string(spec.modes) + ")");
  for (double q : spec.quality_factors) {
    require_positive(q, "quality_factor");
    // The forward solver steps a mode back from a step's end; an overdamped one's fast root grows
    // so fast backwards that the state is lost (config.cpp's range says the same).
    TIPFORCE_THROW_UNLESS(q >= 0.5, "quality_factor must be at least 0.5 (an overdamped mode is not supported), got " +
                                        std::to_string(q));
  }

  const double b1 = clamped_free_root(0);
  double omega1 = 0;
  if (const auto* g = std::get_if<BeamGeometry>(&spec.cantilever)) {
    require_positive(g->length_m, "length_m");
    require_positive(g->width_m, "width_m");
    require_positive(g->thickness_m, "thickness_m");
    require_positive(g->youngs_modulus_pa, "youngs_modulus_pa");
    require_positive(g->density_kg_m3, "density_kg_m3");
    const double ei = g->youngs_modulus_pa * g->width_m * std::pow(g->thickness_m, 3) / 12.0;
    const double mu = g->density_kg_m3 * g->width_m * g->thickness_m;
    const double L = g->length_m;
    modal_mass_kg_ = mu * L;
    static_stiffness_n_per_m_ = 3.0 * ei / (L * L * L);
    omega1 = b1 * b1 * std::sqrt(ei / (mu * L * L * L * L));
  } else {
    const auto& c = std::get<CalibratedProbe>(spec.cantilever);
    require_positive(c.f1_hz, "f1_hz");
    require_positive(c.k_c_n_per_m, "k_c_n_per_m");
    omega1 = 2.0 * std::numbers::pi * c.f1_hz;
    static_stiffness_n_per_m_ = c.k_c_n_per_m;
    // k_c = 3 EI / L^3 and omega1^2 = b1^4 EI / (mu L^4) give mu L without needing L.
    modal_mass_kg_ = std::pow(b1, 4) * c.k_c_n_per_m / (3.0 * omega1 * omega1);
  }

  const auto& gl = detail::gauss_legendre_unit(256);
  for (int i = 0; i < spec.modes; ++i) {
    Mode m;
    m.beta_l = clamped_free_root(i);
    m.omega_rad_per_s = omega1 * (m.beta_l / b1) * (m.beta_l / b1);
    m.frequency_hz = m.omega_rad_per_s / (2.0 * std::numbers::pi);
    m.quality_factor = spec.quality_factors.size() == 1 ? spec.quality_factors[0] : spec.quality_factors[i];
    m.zeta = 1.0 / (2.0 * m.quality_factor);
    // Normalise numerically so that the integral of phi^2 over [0, 1] is 1, whatever the closed form says.
    double norm2 = 0, mean = 0;
    for (std::size_t k = 0; k < gl.nodes.size(); ++k) {
      const double phi = mode_shape(m.beta_l, gl.nodes[k]);
      norm2 += gl.weights[k] * phi * phi;
      mean += gl.weights[k] * phi;
    }
    const double scale = 1.0 / std::sqrt(norm2);
    m.phi_tip = scale * mode_shape(m.beta_l, 1.0);
    m.slope_tip = scale * mode_shape_slope(m.beta_l, 1.0);
    m.gamma = scale * mean;
    modes_.push_back(m);
  }
}

double ModalModel::sensor_gain(int mode) const {
  const Mode& m = modes_.at(static_cast<std::size_t>(mode));
  return sensor_ == Sensor::displacement ? m.phi_tip : m.slope_tip * (2.0 / 3.0);
}

ProbeSpec paper_probe_spec(int modes) {
  ProbeSpec spec;
  spec.cantilever = BeamGeometry{525e-6, 35e-6, 5e-6, 1.76e11, 2330};
  spec.quality_factors = {100.0};
  spec.modes = modes;
  return spec;
}

}  // namespace tipforce
