#pragma once
// Composite Gauss-Legendre rules on [0, 1]: mode-shape integrals and the hold integrals of the
// exact discretisation are smooth, so a composite rule is exact to rounding.
#include <cmath>
#include <numbers>
#include <vector>

namespace tipforce::detail {

struct QuadratureRule {
  std::vector<double> nodes, weights;
};

// `panels` panels of 8-point Gauss-Legendre on [0, 1].
inline QuadratureRule make_gauss_legendre_unit(int panels) {
  static constexpr double x8[4] = {0.1834346424956498, 0.5255324099163290, 0.7966664774136267, 0.9602898564975363};
  static constexpr double w8[4] = {0.3626837833783620, 0.3137066458778873, 0.2223810344533745, 0.1012285362903763};
  QuadratureRule r;
  const double h = 1.0 / panels;
  for (int p = 0; p < panels; ++p) {
    const double mid = (p + 0.5) * h;
    for (int k = 0; k < 4; ++k) {
      for (int s : {-1, 1}) {
        r.nodes.push_back(mid + s * 0.5 * h * x8[k]);
        r.weights.push_back(0.5 * h * w8[k]);
      }
    }
  }
  return r;
}

inline const QuadratureRule& gauss_legendre_unit(int panels) {
  // Immutable after construction: a cache of constants, not mutable state.
  static const QuadratureRule r256 = make_gauss_legendre_unit(256);
  static const QuadratureRule r64 = make_gauss_legendre_unit(64);
  return panels >= 256 ? r256 : r64;
}

}  // namespace tipforce::detail
