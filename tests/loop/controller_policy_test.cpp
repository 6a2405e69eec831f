// The example controller's policy (tools/examples/setpoint_controller/controller_policy.hpp): its
// rate limits, hysteresis and ranges, command by command.
#include <gtest/gtest.h>

#include "controller_policy.hpp"

namespace {

using tipforce::setpoint_command_t;
using tipforce_example::Action;
using tipforce_example::ControllerOptions;
using tipforce_example::ControllerPolicy;

setpoint_command_t command(std::int64_t seq, int status, double z_offset_m = 0, double free_amplitude_m = 20e-9) {
  setpoint_command_t c{};
  c.probe = "afm1";
  c.seq = seq;
  c.status = static_cast<std::int8_t>(status);
  c.free_amplitude_m = free_amplitude_m;
  c.current_free_amplitude_m = 20e-9;
  c.z_offset_m = z_offset_m;
  c.max_peak_force_n = 2e-9;
  c.target_peak_force_n = 1.7e-9;
  c.hold_peak_force_n = 1.0e-9;
  c.hold_peak_force_sigma_n = 0.1e-9;
  c.dpeak_dz_n_per_m = -1.0;  // 1 nN per nm
  c.dpeak_dfree_amplitude_n_per_m = 0.1;
  return c;
}

ControllerOptions options() {
  ControllerOptions o;
  o.nominal_free_amplitude_m = 20e-9;
  o.min_free_amplitude_m = 18e-9;
  o.max_retract_m = 3e-9;
  o.max_z_step_m = 1e-9;
  o.max_amplitude_step_m = 0.5e-9;
  o.relax_z_step_m = 0.2e-9;
  o.relax_amplitude_step_m = 0.1e-9;
  o.relax_after = 3;
  return o;
}

TEST(ControllerPolicy, ACorrectionIsAppliedAtOnceButAtMostOneStepAndWithinTheRange) {
  ControllerPolicy p(options());
  auto d = p.on_command(command(0, setpoint_command_t::STATUS_CORRECTION, 0.4e-9, 19.8e-9));
  EXPECT_EQ(d.action, Action::correct);
  EXPECT_DOUBLE_EQ(d.setpoints.z_offset_m, 0.4e-9);
  EXPECT_DOUBLE_EQ(d.setpoints.free_amplitude_m, 19.8e-9);
  d = p.on_command(command(1, setpoint_command_t::STATUS_OUT_OF_RANGE, 5e-9, 10e-9));  // far more than allowed
  EXPECT_DOUBLE_EQ(d.setpoints.z_offset_m, 1.4e-9);                                  // one step
  EXPECT_DOUBLE_EQ(d.setpoints.free_amplitude_m, 19.3e-9);                           // one step
  for (int i = 2; i < 8; ++i) d = p.on_command(command(i, setpoint_command_t::STATUS_CORRECTION, 1e-9, 10e-9));
  EXPECT_DOUBLE_EQ(d.setpoints.z_offset_m, 3e-9);           // the total range
  EXPECT_DOUBLE_EQ(d.setpoints.free_amplitude_m, 18e-9);    // the minimum
  EXPECT_NE(d.reason.find("nothing left to change"), std::string::npos) << d.reason;
}

TEST(ControllerPolicy, ItRelaxesOnlyAfterEnoughCommandsUnderTheLimitAndStepByStep) {
  ControllerPolicy p(options());
  p.on_command(command(0, setpoint_command_t::STATUS_CORRECTION, 1e-9, 19.5e-9));
  for (int i = 1; i <= 2; ++i) EXPECT_EQ(p.on_command(command(i, setpoint_command_t::STATUS_UNDER_LIMIT)).action, Action::hold);
  auto d = p.on_command(command(3, setpoint_command_t::STATUS_UNDER_LIMIT));
  EXPECT_EQ(d.action, Action::relax);
  EXPECT_DOUBLE_EQ(d.setpoints.z_offset_m, 0.8e-9);
  EXPECT_DOUBLE_EQ(d.setpoints.free_amplitude_m, 19.6e-9);
  // A correction resets the count.
  p.on_command(command(4, setpoint_command_t::STATUS_CORRECTION, 0.1e-9, 19.6e-9));
  EXPECT_EQ(p.on_command(command(5, setpoint_command_t::STATUS_UNDER_LIMIT)).action, Action::hold);
  // And it never goes past the nominal setpoints.
  for (int i = 6; i < 40; ++i) d = p.on_command(command(i, setpoint_command_t::STATUS_UNDER_LIMIT));
  EXPECT_DOUBLE_EQ(d.setpoints.z_offset_m, 0);
  EXPECT_DOUBLE_EQ(d.setpoints.free_amplitude_m, 20e-9);
  EXPECT_EQ(d.action, Action::hold);
}

TEST(ControllerPolicy, ItRelaxesOnlyAsFarAsTheSensitivitiesLeaveRoom) {
  ControllerPolicy p(options());
  p.on_command(command(0, setpoint_command_t::STATUS_CORRECTION, 1e-9));
  for (int i = 1; i <= 2; ++i) p.on_command(command(i, setpoint_command_t::STATUS_UNDER_LIMIT));
  auto c = command(3, setpoint_command_t::STATUS_UNDER_LIMIT);
  // room = 0.9 x 1.7 - (1.45 + 0.1) = -0.02 nN: none.
  c.hold_peak_force_n = 1.45e-9;
  auto d = p.on_command(c);
  EXPECT_EQ(d.action, Action::hold);
  EXPECT_NE(d.reason.find("no room"), std::string::npos);
  // room = 1.53 - (1.38 + 0.1) = 0.05 nN at 1 nN/nm: 0.05 nm, less than the 0.2 nm step.
  c.seq = 4;
  c.hold_peak_force_n = 1.38e-9;
  d = p.on_command(c);
  EXPECT_EQ(d.action, Action::relax);
  EXPECT_NEAR(d.setpoints.z_offset_m, 1e-9 - 0.05e-9, 1e-15);
}

TEST(ControllerPolicy, NoAdviceAndStaleCommandsChangeNothing) {
  ControllerOptions o = options();
  o.dead_pixels = 2;
  ControllerPolicy p(o);
  auto d = p.on_command(command(10, setpoint_command_t::STATUS_CORRECTION, 0.5e-9));
  EXPECT_EQ(d.action, Action::correct);
  // Windows 11 and 12 were acquired before that change took effect (two pixels of latency).
  for (int seq : {11, 12}) {
    d = p.on_command(command(seq, setpoint_command_t::STATUS_CORRECTION, 0.5e-9));
    EXPECT_EQ(d.action, Action::hold);
    EXPECT_NE(d.reason.find("stale"), std::string::npos);
  }
  d = p.on_command(command(13, setpoint_command_t::STATUS_NO_ADVICE));
  EXPECT_EQ(d.action, Action::hold);
  EXPECT_DOUBLE_EQ(d.setpoints.z_offset_m, 0.5e-9);
  EXPECT_EQ(p.on_command(command(14, setpoint_command_t::STATUS_CORRECTION, 0.5e-9)).action, Action::correct);
}

TEST(ControllerPolicy, WithoutANominalAmplitudeItTakesTheFirstCommandsAndKeepsIt) {
  ControllerOptions o;
  ControllerPolicy p(o);
  auto c = command(0, setpoint_command_t::STATUS_CORRECTION, 0.3e-9, 15e-9);
  c.current_free_amplitude_m = 19e-9;
  const auto d = p.on_command(c);
  EXPECT_DOUBLE_EQ(p.nominal_free_amplitude_m(), 19e-9);
  EXPECT_DOUBLE_EQ(d.setpoints.free_amplitude_m, 19e-9);  // no minimum given: the amplitude is not a setpoint
  EXPECT_DOUBLE_EQ(d.setpoints.z_offset_m, 0.3e-9);
}

}  // namespace
