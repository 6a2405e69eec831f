#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

#include "test_support.hpp"

namespace tipforce {
namespace {
using testing::paper_probe;

TEST(Cantilever, PaperCantileverHasPublishedFirstResonanceAndStiffness) {
  const ModalModel modal(paper_probe());
  EXPECT_NEAR(modal.modes()[0].frequency_hz, 25468.9, 0.5);
  EXPECT_NEAR(modal.static_stiffness_n_per_m(), 1.330, 0.002);
  // mu L from rho w t L, independently.
  EXPECT_NEAR(modal.modal_mass_kg(), 2330 * 35e-6 * 5e-6 * 525e-6, 1e-18);
}

TEST(Cantilever, RootsOfFrequencyEquationMatchTablesAndAsymptote) {
  const double table[] = {1.8751040687, 4.6940911330, 7.8547574382, 10.9955407349, 14.1371683910};
  for (int i = 0; i < 5; ++i) {
    const double x = clamped_free_root(i);
    EXPECT_NEAR(x, table[i], 1e-9);
    EXPECT_NEAR(std::cos(x) * std::cosh(x) + 1.0, 0.0, 1e-6 * std::cosh(x));
  }
  // For high modes beta L -> (2i - 1) pi / 2.
  EXPECT_NEAR(clamped_free_root(29), (2 * 30 - 1) * std::numbers::pi / 2, 1e-9);
}

TEST(Cantilever, ModeShapesAreNormalisedOrthogonalAndFiniteForHighModes) {
  const ModalModel modal(paper_probe(20));
  const double gamma_expected[] = {0.7830, 0.4339, 0.2544};
  for (int i = 0; i < 3; ++i) EXPECT_NEAR(modal.modes()[i].gamma, gamma_expected[i], 1e-4);
  // Composite Simpson with 20000 intervals: independent of the library's Gauss-Legendre rule.
  const int n = 20000;
  auto integral = [&](auto&& f) {
    double s = f(0.0) + f(1.0);
    for (int k = 1; k < n; ++k) s += (k % 2 ? 4.0 : 2.0) * f(static_cast<double>(k) / n);
    return s / (3.0 * n);
  };
  for (int i : {0, 1, 4, 19}) {
    const double b = modal.modes()[i].beta_l;
    const double scale = modal.modes()[i].phi_tip / mode_shape(b, 1.0);
    EXPECT_NEAR(std::abs(modal.modes()[i].phi_tip), 2.0, 1e-9) << "mode " << i;
    EXPECT_NEAR(integral([&](double x) { return std::pow(scale * mode_shape(b, x), 2); }), 1.0, 1e-6) << "mode " << i;
    EXPECT_TRUE(std::isfinite(modal.modes()[i].slope_tip));
    // Clamped end: phi(0) = 0, phi'(0) = 0.
    EXPECT_NEAR(mode_shape(b, 0.0), 0.0, 1e-9);
    EXPECT_NEAR(mode_shape_slope(b, 0.0), 0.0, 1e-7 * b);
  }
  const double b1 = modal.modes()[0].beta_l, b2 = modal.modes()[1].beta_l;
  EXPECT_NEAR(integral([&](double x) { return mode_shape(b1, x) * mode_shape(b2, x); }), 0.0, 1e-6);
  // Euler-Bernoulli: the tip slope of mode 1, L phi'(L), is 2.7530 for |phi(L)| = 2 (Meirovitch).
  EXPECT_NEAR(modal.modes()[0].slope_tip, 2.7530, 1e-3);
}

TEST(Cantilever, CalibratedProbeReproducesGeometricProbe) {
  const ModalModel geo(paper_probe());
  ProbeSpec cal = paper_probe();
  cal.cantilever = CalibratedProbe{geo.modes()[0].frequency_hz, geo.static_stiffness_n_per_m()};
  const ModalModel c(cal);
  EXPECT_NEAR(c.modal_mass_kg() / geo.modal_mass_kg(), 1.0, 1e-12);
  for (int i = 0; i < 8; ++i) EXPECT_NEAR(c.modes()[i].frequency_hz / geo.modes()[i].frequency_hz, 1.0, 1e-12);
}

TEST(Cantilever, ModalStaticComplianceConvergesToBeamCompliance) {
  // A static tip load F deflects the tip by F / k_c; in modes, sum phi_i(L)^2 / (mu L omega_i^2).
  const ModalModel modal(paper_probe(30));
  double compliance = 0;
  for (const Mode& m : modal.modes()) compliance += m.phi_tip * m.phi_tip / (modal.modal_mass_kg() * m.omega_rad_per_s * m.omega_rad_per_s);
  EXPECT_NEAR(compliance * modal.static_stiffness_n_per_m(), 1.0, 1e-4);
}

TEST(Cantilever, BadGeometryIsRejectedNamingTheField) {
  ProbeSpec spec = paper_probe();
  std::get<BeamGeometry>(spec.cantilever).thickness_m = -1;
  try {
    ModalModel m(spec);
    FAIL() << "expected an exception";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("thickness_m"), std::string::npos) << e.what();
  }
}

// An overdamped mode is refused where the model is made (the solver's step back from a step's end
// lost its state: NaN at 2e-6 s with 8 modes at Q 0.3); critical damping is the limit.
TEST(Cantilever, AnOverdampedModeIsRejectedNamingTheQualityFactor) {
  ProbeSpec spec = paper_probe();
  spec.quality_factors = {0.3};
  try {
    ModalModel m(spec);
    FAIL() << "expected an exception";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("quality_factor must be at least 0.5"), std::string::npos) << e.what();
  }
  spec.quality_factors = {0.5};
  EXPECT_NO_THROW(ModalModel{spec});
}

}  // namespace
}  // namespace tipforce
