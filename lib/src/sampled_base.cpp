#include "sampled_base.hpp"

#include "tipforce/assert.hpp"

namespace tipforce::detail {

namespace {

// The three samples past the ends (-1, n, n + 1) of an array stored from sample -1, continued
// linearly from the two nearest. Low order on purpose: extrapolation multiplies the samples' noise,
// and a measured base is noisy (the samples continued by a cubic and differenced to fourth order
// would put about four times an interior sample's noise into the first and last steps' drive).
void continue_linearly(std::vector<double>& s, int n) {
  s[0] = 2 * s[1] - s[2];                        // sample -1
  s[n + 1] = 2 * s[n] - s[n - 1];                // sample n
  s[n + 2] = 2 * s[n + 1] - s[n];                // sample n + 1
}

}  // namespace

SampledBase make_sampled_base(const std::vector<double>& y, double sample_period_s) {
  const int n = static_cast<int>(y.size());
  TIPFORCE_DEMAND(n >= 3 && sample_period_s > 0);
  const double h = sample_period_s;
  SampledBase s;
  const std::size_t m = static_cast<std::size_t>(n) + 3;
  s.y_m.assign(m, 0.0);
  s.yd_m_per_s.assign(m, 0.0);
  s.ydd_m_per_s2.assign(m, 0.0);
  double* yv = s.y_m.data() + 1;  // yv[i]: sample i, i in -1 .. n + 1
  double* vv = s.yd_m_per_s.data() + 1;
  double* av = s.ydd_m_per_s2.data() + 1;
  for (int i = 0; i < n; ++i) yv[i] = y[static_cast<std::size_t>(i)];
  // Fourth-order central differences where five samples fit, second-order where three do.
  for (int i = 1; i + 1 < n; ++i) {
    if (i >= 2 && i + 2 < n) {
      vv[i] = (yv[i - 2] - 8 * yv[i - 1] + 8 * yv[i + 1] - yv[i + 2]) / (12 * h);
      av[i] = (-yv[i - 2] + 16 * yv[i - 1] - 30 * yv[i] + 16 * yv[i + 1] - yv[i + 2]) / (12 * h * h);
    } else {
      vv[i] = (yv[i + 1] - yv[i - 1]) / (2 * h);
      av[i] = (yv[i + 1] - 2 * yv[i] + yv[i - 1]) / (h * h);
    }
  }
  // The end samples' velocity and acceleration from their two inner neighbours (n = 3: both ends
  // from the one middle sample).
  if (n >= 4) {
    vv[0] = 2 * vv[1] - vv[2];
    av[0] = 2 * av[1] - av[2];
    vv[n - 1] = 2 * vv[n - 2] - vv[n - 3];
    av[n - 1] = 2 * av[n - 2] - av[n - 3];
  } else {
    vv[0] = vv[2] = vv[1];
    av[0] = av[2] = av[1];
  }
  // The position past the ends by the parabola through the three nearest samples; velocity and
  // acceleration linearly.
  yv[-1] = 3 * yv[0] - 3 * yv[1] + yv[2];
  yv[n] = 3 * yv[n - 1] - 3 * yv[n - 2] + yv[n - 3];
  yv[n + 1] = 3 * yv[n] - 3 * yv[n - 1] + yv[n - 2];
  continue_linearly(s.yd_m_per_s, n);
  continue_linearly(s.ydd_m_per_s2, n);
  return s;
}

}  // namespace tipforce::detail
