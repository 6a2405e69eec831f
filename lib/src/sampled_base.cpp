#include "sampled_base.hpp"

#include "tipforce/assert.hpp"

namespace tipforce::detail {

namespace {
// Samples continued this far past each end: the five-point stencils at samples -1 and n + 1 reach samples -3 and n + 3.
constexpr int kGhosts = 4;
}  // namespace

SampledBase make_sampled_base(const std::vector<double>& y, double sample_period_s) {
  const int n = static_cast<int>(y.size());
  TIPFORCE_DEMAND(n >= 3 && sample_period_s > 0);
  // e[i + kGhosts] is sample i, for i in -kGhosts .. n - 1 + kGhosts.
  std::vector<double> e(static_cast<std::size_t>(n + 2 * kGhosts));
  for (int i = 0; i < n; ++i) e[i + kGhosts] = y[i];
  // A vanishing fourth (third) difference: the cubic (parabola) through the samples nearest the end.
  const bool cubic = n >= 4;
  for (int g = 0; g < kGhosts; ++g) {
    const int hi = n + kGhosts + g, lo = kGhosts - 1 - g;
    if (cubic) {
      e[hi] = 4 * e[hi - 1] - 6 * e[hi - 2] + 4 * e[hi - 3] - e[hi - 4];
      e[lo] = 4 * e[lo + 1] - 6 * e[lo + 2] + 4 * e[lo + 3] - e[lo + 4];
    } else {
      e[hi] = 3 * e[hi - 1] - 3 * e[hi - 2] + e[hi - 3];
      e[lo] = 3 * e[lo + 1] - 3 * e[lo + 2] + e[lo + 3];
    }
  }
  SampledBase s;
  const std::size_t m = static_cast<std::size_t>(n) + 3;
  s.y_m.resize(m);
  s.yd_m_per_s.resize(m);
  s.ydd_m_per_s2.resize(m);
  const double h = sample_period_s;
  for (int i = -1; i <= n + 1; ++i) {
    const double* c = &e[i + kGhosts];
    const std::size_t k = static_cast<std::size_t>(i + 1);
    s.y_m[k] = c[0];
    s.yd_m_per_s[k] = (c[-2] - 8 * c[-1] + 8 * c[1] - c[2]) / (12 * h);
    s.ydd_m_per_s2[k] = (-c[-2] + 16 * c[-1] - 30 * c[0] + 16 * c[1] - c[2]) / (12 * h * h);
  }
  return s;
}

}  // namespace tipforce::detail
