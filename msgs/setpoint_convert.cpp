#include "tipforce/setpoint_convert.hpp"

namespace tipforce::lcmio {

static_assert(setpoint_command_t::STATUS_UNDER_LIMIT == static_cast<int>(AdviceStatus::under_limit));
static_assert(setpoint_command_t::STATUS_CORRECTION == static_cast<int>(AdviceStatus::correction));
static_assert(setpoint_command_t::STATUS_OUT_OF_RANGE == static_cast<int>(AdviceStatus::out_of_range));
static_assert(setpoint_command_t::STATUS_NO_ADVICE == static_cast<int>(AdviceStatus::no_advice));

setpoint_command_t to_command(const WindowHeader& header, const Advice& a, const AdvisorOptions& options,
                              int64_t publish_utime) {
  setpoint_command_t c;
  c.utime = header.utime;
  c.probe = header.probe;
  c.seq = header.seq;
  c.pixel_x = header.pixel_x;
  c.pixel_y = header.pixel_y;
  c.status = static_cast<int8_t>(a.status);
  c.reason = a.reason;
  c.free_amplitude_m = a.free_amplitude_m;
  c.z_offset_m = a.z_offset_m;
  c.predicted_peak_force_n = a.predicted_peak_force_n;
  c.predicted_peak_force_sigma_n = a.predicted_sigma_n;
  c.hold_peak_force_n = a.hold_peak_force_n;
  c.hold_peak_force_sigma_n = a.hold_sigma_n;
  c.dpeak_dfree_amplitude_n_per_m = a.dpeak_dfree_amplitude_n_per_m;
  c.dpeak_dz_n_per_m = a.dpeak_dz_n_per_m;
  c.current_free_amplitude_m = a.current_free_amplitude_m;
  c.separation_m = a.separation_m;
  c.max_peak_force_n = options.max_peak_force_n;
  c.target_peak_force_n = a.target_peak_force_n;
  c.forward_solves = a.forward_solves;
  c.publish_utime = publish_utime;
  return c;
}

}  // namespace tipforce::lcmio
