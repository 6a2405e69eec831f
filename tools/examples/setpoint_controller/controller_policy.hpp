#pragma once
// The example controller's policy (issue 13; tools/examples/setpoint_controller/README.md): what
// to do with each setpoint_command_t from tipforced's advisor. It keeps the instrument's two
// setpoints, the free amplitude and a z offset from the user's nominal separation, and moves them
// - at once, but at most max_z_step_m and max_amplitude_step_m per command, when the advisor asks
//   for a correction (safety first: the force is predicted over the limit);
// - back toward the nominal setpoints, slowly (relax_z_step_m per command), after relax_after
//   commands in a row that say the force is under the limit, and only as far as the advisor's
//   sensitivities predict the force stays under (1 - relax_band) x the aim (hysteresis);
// - never: on a command for a window acquired before the last change took effect (dead_pixels),
//   and on NO_ADVICE (a fit not trusted says nothing either way).
// Both setpoints stay within what the user allows: the free amplitude in [min, nominal], the z
// offset in [0, max_retract_m] (never closer to the sample than the nominal).
//
// Plain C++ on the lcm-gen type: no LCM runtime, no tipforce library. A lab adapting the example
// keeps this file and replaces the instrument side (setpoint_controller.cpp).
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <sstream>
#include <string>

#include "tipforce/setpoint_command_t.hpp"

namespace tipforce_example {

struct ControllerOptions {
  double nominal_free_amplitude_m = std::numeric_limits<double>::quiet_NaN();  // NaN: the first command's
  double min_free_amplitude_m = 0;       // the lowest free amplitude allowed (0: the nominal, amplitude fixed)
  double max_retract_m = 10e-9;          // the most the z offset may retract from the nominal separation
  double max_z_step_m = 2e-9;            // per command, retracting
  double max_amplitude_step_m = 0.5e-9;  // per command, lowering
  double relax_z_step_m = 0.1e-9;        // per command, approaching the nominal again
  double relax_amplitude_step_m = 0.05e-9;
  // UNDER_LIMIT commands in a row before relaxing: about the cantilever's ring-up time 2Q/omega in
  // pixels (6 for the closed-loop test's 200 us pixels, Q = 100 at 25 kHz). After a correction
  // the amplitude keeps changing that long, and relaxing sooner met its rise (measured: 2 let the
  // force back over the limit 4-5 pixels after each soft-to-hard step, 6 did not).
  int relax_after = 6;
  double relax_band = 0.1;               // relax only while predicted + k sigma stays under (1 - band) x aim
  double sigma_multiplier = 1.0;         // k, as the advisor's (AdvisorOptions::sigma_multiplier)
  std::int64_t dead_pixels = 0;          // windows after a change that were acquired before it took effect
};

struct Setpoints {
  double free_amplitude_m = 0;
  double z_offset_m = 0;  // from the nominal separation, + retracts
};

enum class Action : std::int8_t { hold = 0, correct = 1, relax = 2 };

struct Decision {
  Setpoints setpoints;
  Action action = Action::hold;
  std::string reason;
};

class ControllerPolicy {
 public:
  explicit ControllerPolicy(ControllerOptions options) : o_(options) {}

  Decision on_command(const tipforce::setpoint_command_t& c) {
    if (!started_) start(c);
    Decision d{now_, Action::hold, ""};
    if (changed_ && c.seq <= last_change_seq_ + o_.dead_pixels) {
      d.reason = "stale: window acquired before the last change took effect";
      return d;
    }
    switch (c.status) {
      case tipforce::setpoint_command_t::STATUS_CORRECTION:
      case tipforce::setpoint_command_t::STATUS_OUT_OF_RANGE:
        under_in_a_row_ = 0;
        return correct(c);
      case tipforce::setpoint_command_t::STATUS_UNDER_LIMIT:
        ++under_in_a_row_;
        return relax(c);
      default:
        under_in_a_row_ = 0;
        d.reason = "no advice: hold (" + c.reason + ")";
        return d;
    }
  }

  const Setpoints& setpoints() const { return now_; }
  double nominal_free_amplitude_m() const { return nominal_amplitude_; }

 private:
  void start(const tipforce::setpoint_command_t& c) {
    started_ = true;
    nominal_amplitude_ = std::isnan(o_.nominal_free_amplitude_m) ? c.current_free_amplitude_m : o_.nominal_free_amplitude_m;
    min_amplitude_ = o_.min_free_amplitude_m > 0 ? std::min(o_.min_free_amplitude_m, nominal_amplitude_) : nominal_amplitude_;
    now_ = Setpoints{nominal_amplitude_, 0.0};
  }

  Decision correct(const tipforce::setpoint_command_t& c) {
    Setpoints next = now_;
    const double dz = std::clamp(c.z_offset_m, 0.0, o_.max_z_step_m);
    next.z_offset_m = std::min(now_.z_offset_m + dz, o_.max_retract_m);
    // The advisor's amplitude is absolute; lower toward it, step-limited, never below the minimum.
    const double lower_to = std::max({c.free_amplitude_m, now_.free_amplitude_m - o_.max_amplitude_step_m, min_amplitude_});
    if (std::isfinite(c.free_amplitude_m) && lower_to < now_.free_amplitude_m) next.free_amplitude_m = lower_to;
    std::ostringstream why;
    why << "correct: retract " << (next.z_offset_m - now_.z_offset_m) * 1e9 << " nm (asked " << c.z_offset_m * 1e9
        << ")";
    if (next.free_amplitude_m != now_.free_amplitude_m)
      why << ", free amplitude " << now_.free_amplitude_m * 1e9 << " -> " << next.free_amplitude_m * 1e9 << " nm";
    if (next.z_offset_m >= o_.max_retract_m) why << "; z offset at its limit";
    return change(c, next, Action::correct, why.str());
  }

  Decision relax(const tipforce::setpoint_command_t& c) {
    Decision hold{now_, Action::hold, "under the limit"};
    const bool away = now_.z_offset_m > 0 || now_.free_amplitude_m < nominal_amplitude_;
    if (!away || under_in_a_row_ < o_.relax_after) return hold;
    // What the advisor's linear sensitivities predict for a step back; a sensitivity of 0 (no
    // contact) leaves only the step limits.
    const double room = (1 - o_.relax_band) * c.target_peak_force_n -
                        (c.hold_peak_force_n + o_.sigma_multiplier * c.hold_peak_force_sigma_n);
    if (!(room > 0)) {
      hold.reason = "under the limit, but no room to relax";
      return hold;
    }
    const double gz = std::isfinite(c.dpeak_dz_n_per_m) ? std::max(0.0, -c.dpeak_dz_n_per_m) : 0.0;
    const double ga = std::isfinite(c.dpeak_dfree_amplitude_n_per_m) ? std::max(0.0, c.dpeak_dfree_amplitude_n_per_m) : 0.0;
    Setpoints next = now_;
    double dz = std::min(o_.relax_z_step_m, now_.z_offset_m);
    if (gz > 0) dz = std::min(dz, room / gz);
    next.z_offset_m -= dz;
    const double room_left = room - gz * dz;
    double da = std::min(o_.relax_amplitude_step_m, nominal_amplitude_ - now_.free_amplitude_m);
    if (ga > 0) da = std::min(da, std::max(0.0, room_left) / ga);
    next.free_amplitude_m += da;
    std::ostringstream why;
    why << "relax: approach " << dz * 1e9 << " nm, free amplitude +" << da * 1e9 << " nm";
    return change(c, next, Action::relax, why.str());
  }

  Decision change(const tipforce::setpoint_command_t& c, const Setpoints& next, Action action, std::string why) {
    if (next.z_offset_m == now_.z_offset_m && next.free_amplitude_m == now_.free_amplitude_m)
      return Decision{now_, Action::hold, why + " (nothing left to change)"};
    now_ = next;
    changed_ = true;
    last_change_seq_ = c.seq;
    return Decision{now_, action, std::move(why)};
  }

  ControllerOptions o_;
  bool started_ = false;
  double nominal_amplitude_ = 0, min_amplitude_ = 0;
  Setpoints now_;
  bool changed_ = false;
  std::int64_t last_change_seq_ = 0;
  int under_in_a_row_ = 0;
};

}  // namespace tipforce_example
