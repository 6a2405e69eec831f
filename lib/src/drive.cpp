#include "tipforce/drive.hpp"

#include "tipforce/detail/forward_step.hpp"

namespace tipforce {

BaseMotion base_motion(DriveKind kind, double a, double f, double phase, double g, double t) {
  const detail::Motion m = detail::analytic_base_motion(static_cast<int>(kind), a, f, phase, g, t);
  return {m.y, m.yd, m.ydd};
}

}  // namespace tipforce
