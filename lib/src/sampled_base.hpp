#pragma once
// What a sampled base's samples say between them: the base position, velocity and acceleration
// at each sample and one sample period either side, for DriveFunction's cubic interpolation
// (forward_step.hpp). Shared by the forward solver and the reference, which must read the same
// samples the same way for the one to check the other.
#include <vector>

namespace tipforce::detail {

struct SampledBase {
  // Samples -1 .. n + 1 of a window of n: n + 3 values each.
  std::vector<double> y_m, yd_m_per_s, ydd_m_per_s2;
};

// y: the window's base samples (at least 3), sample_period_s apart. Fourth-order central
// differences inside, second-order ones next to the ends, and the ends and the samples past them
// continued at low order (see sampled_base.cpp: a measured base is noisy, and extrapolation
// multiplies noise).
SampledBase make_sampled_base(const std::vector<double>& y, double sample_period_s);

}  // namespace tipforce::detail
