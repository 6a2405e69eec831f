#pragma once
// Tip-sample force models (SPEC section 1). Force is positive toward the sample; z is the
// absolute tip position toward the sample, h the rest-position-to-surface separation.
#include <optional>
#include <span>
#include <string>
#include <string_view>

namespace tipforce {

enum class ForceModelKind { none, spring, kelvin_voigt, hertz, dmt, dmt_viscous };

std::string_view to_string(ForceModelKind kind);
std::optional<ForceModelKind> force_model_from_string(std::string_view name);
// Parameter names of a model, in the order the solver takes them.
std::span<const std::string_view> force_model_parameters(ForceModelKind kind);

// Drive parameters that may be unknowns, appended after the model's parameters in a full vector.
inline constexpr std::string_view kDriveParameterNames[] = {"drive_amplitude_m", "drive_frequency_hz",
                                                            "drive_phase_rad", "drive_chirp_hz_per_s"};
inline constexpr int kDriveParameterCount = 4;

// Parameters of any model, by name; unused fields are ignored.
struct ForceParams {
  double k_n_per_m = 0, c_ns_per_m = 0, h_m = 0, e_star_pa = 0, radius_m = 0, hamaker_j = 0, a0_m = 0,
         eta_pa_s = 0;
};
// Reads a model's parameters from the first entries of a full parameter vector.
ForceParams force_params_from(ForceModelKind kind, std::span<const double> values);

// The force law, evaluated exactly as SPEC section 1 states it: the reference for the solvers.
double tip_sample_force_n(ForceModelKind kind, const ForceParams& p, double z_m, double zdot_m_per_s);
// Penetration into the sample (>= 0), as the model measures it: z - h, or a0 - (h - z) for DMT.
double indentation_m(ForceModelKind kind, const ForceParams& p, double z_m);

}  // namespace tipforce
