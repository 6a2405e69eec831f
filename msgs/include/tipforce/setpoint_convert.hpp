#pragma once
// The setpoint advisor's Advice (lib) as the setpoint_command_t message (issue 13).
#include <cstdint>

#include "tipforce/lcm_convert.hpp"
#include "tipforce/setpoint_advisor.hpp"
#include "tipforce/setpoint_command_t.hpp"

namespace tipforce::lcmio {

setpoint_command_t to_command(const WindowHeader& header, const Advice& advice, const AdvisorOptions& options,
                              int64_t publish_utime);

}  // namespace tipforce::lcmio
