#pragma once
// Base (dither piezo) excitation on the drive's own clock (SPEC section 1).
#include <vector>

namespace tipforce {

enum class DriveKind { sine = 0, chirp = 1, sampled = 2 };

struct Drive {
  DriveKind kind = DriveKind::sine;
  double amplitude_m = 0;
  double frequency_hz = 0;
  double phase_rad = 0;
  double chirp_hz_per_s = 0;
  std::vector<double> base_m;  // DriveKind::sampled: y per sample of the window
};

// Position, velocity and acceleration of the base at time t_s (analytic drives).
struct BaseMotion {
  double y_m, ydot_m_per_s, yddot_m_per_s2;
};
BaseMotion base_motion(DriveKind kind, double amplitude_m, double frequency_hz, double phase_rad,
                       double chirp_hz_per_s, double t_s);

}  // namespace tipforce
