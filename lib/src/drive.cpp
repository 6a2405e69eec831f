#include "tipforce/drive.hpp"

#include <cmath>
#include <numbers>

namespace tipforce {

BaseMotion base_motion(DriveKind kind, double a, double f, double phase, double g, double t) {
  constexpr double two_pi = 2.0 * std::numbers::pi;
  if (kind == DriveKind::chirp) {
    // y = a sin(2 pi (f + g t) t + phase): instantaneous frequency f + 2 g t.
    const double th = two_pi * (f + g * t) * t + phase;
    const double thd = two_pi * (f + 2.0 * g * t);
    const double thdd = 2.0 * two_pi * g;
    const double s = std::sin(th), c = std::cos(th);
    return {a * s, a * c * thd, a * (c * thdd - s * thd * thd)};
  }
  const double w = two_pi * f;
  const double th = w * t + phase;
  const double s = std::sin(th), c = std::cos(th);
  return {a * s, a * w * c, -a * w * w * s};
}

}  // namespace tipforce
