// InversionOptions::problem: every tuning value's range, checked once where a probe's options
// enter the library (the Inverter), so that a caller's typo is an error naming the option rather
// than a fit that quietly does something else. The config reader checks the options it exposes
// with the same ranges or narrower ones.
#include <cmath>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "tipforce/inversion.hpp"

namespace tipforce {
namespace {

class RangeCheck {
 public:
  // lo <= v <= hi (lo_open / hi_open: strict), finite.
  RangeCheck& number(const char* name, double v, double lo, double hi, bool lo_open = false, bool hi_open = false) {
    if (!problem_.empty()) return *this;
    const bool ok = std::isfinite(v) && (lo_open ? v > lo : v >= lo) && (hi_open ? v < hi : v <= hi);
    if (!ok) {
      std::ostringstream o;
      o << name << " = " << v << ": must be finite and in " << (lo_open ? "(" : "[") << lo << ", " << hi
        << (hi_open ? ")" : "]");
      problem_ = o.str();
    }
    return *this;
  }
  RangeCheck& count(const char* name, long v, long lo, long hi = 1'000'000'000L) {
    if (!problem_.empty() || (v >= lo && v <= hi)) return *this;
    problem_ = std::string(name) + " = " + std::to_string(v) + ": must be in [" + std::to_string(lo) + ", " +
               std::to_string(hi) + "]";
    return *this;
  }
  RangeCheck& each(const char* name, const std::vector<double>& v, double lo, double hi, bool lo_open = false) {
    for (std::size_t i = 0; i < v.size() && problem_.empty(); ++i)
      number((std::string(name) + "[" + std::to_string(i) + "]").c_str(), v[i], lo, hi, lo_open);
    return *this;
  }
  RangeCheck& order(const char* low_name, double low, const char* high_name, double high) {
    if (problem_.empty() && !(low <= high))
      problem_ = std::string(low_name) + " exceeds " + high_name;
    return *this;
  }
  std::optional<std::string> result() const {
    return problem_.empty() ? std::nullopt : std::optional<std::string>(problem_);
  }

 private:
  std::string problem_;
};

constexpr double kHuge = 1e300;

}  // namespace

std::optional<std::string> InversionOptions::problem() const {
  RangeCheck c;
  c.number("deadline_ms", deadline_ms, 0, 3.6e6).each("prepare_sample_periods_s", prepare_sample_periods_s, 0, 1, true);
  c.count("swarm_size", swarm_size, 1).count("max_generations", max_generations, 1);
  c.count("warm_swarm_size", warm_swarm_size, 1).count("warm_max_generations", warm_max_generations, 1);
  c.count("stall_generations", stall_generations, 1).number("stall_rel_tolerance", stall_rel_tolerance, 0, 1);
  c.number("swarm_inertia", swarm_inertia, 0, 1).number("swarm_acceleration", swarm_acceleration, 0, 10);
  c.number("swarm_max_velocity", swarm_max_velocity, 0, 1, true).number("swarm_wall_restitution", swarm_wall_restitution, 0, 1);
  c.number("swarm_initial_velocity", swarm_initial_velocity, 0, 1).number("warm_spread_sigmas", warm_spread_sigmas, 0, kHuge);
  c.number("warm_spread_min", warm_spread_min, 0, 1).number("warm_spread_max", warm_spread_max, 0, 1);
  c.order("warm_spread_min", warm_spread_min, "warm_spread_max", warm_spread_max);
  c.number("warm_spread_no_sigma", warm_spread_no_sigma, 0, 1).count("reach_particle_every", reach_particle_every, 0);
  c.count("cold_physics_grid", cold_physics_grid, 0).number("grid_periods", grid_periods, 0, kHuge);
  c.each("cold_physics_indentation_fractions", cold_physics_indentation_fractions, 0, 1);
  c.count("cold_physics_grid_further", cold_physics_grid_further, 1).count("cold_physics_max_candidates", cold_physics_max_candidates, 0);
  c.count("cold_physics_polishes", cold_physics_polishes, 1).number("cold_physics_second_ratio", cold_physics_second_ratio, 1, kHuge);
  c.count("cold_physics_polishes_further", cold_physics_polishes_further, 1);
  c.number("cold_physics_second_ratio_further", cold_physics_second_ratio_further, 1, kHuge);
  c.number("cold_physics_max_lag1", cold_physics_max_lag1, -1, 1).number("cold_physics_accept_misfit", cold_physics_accept_misfit, 0, kHuge);
  c.count("lm_max_iterations", lm_max_iterations, 0).count("cold_lm_max_iterations", cold_lm_max_iterations, 0);
  c.number("lm_initial_lambda", lm_initial_lambda, 0, kHuge, true);
  c.number("lm_initial_lambda_continued", lm_initial_lambda_continued, 0, kHuge, true);
  c.number("lm_lambda_down", lm_lambda_down, 1, kHuge, true).number("lm_lambda_up", lm_lambda_up, 1, kHuge, true);
  c.number("lm_lambda_up_singular", lm_lambda_up_singular, 1, kHuge, true).number("lm_min_lambda", lm_min_lambda, 0, kHuge);
  c.count("lm_max_tries", lm_max_tries, 1).number("lm_min_shrink", lm_min_shrink, 0, 1, true);
  c.number("lm_max_shrink", lm_max_shrink, 0, 1, true).order("lm_min_shrink", lm_min_shrink, "lm_max_shrink", lm_max_shrink);
  c.number("lm_min_diagonal", lm_min_diagonal, 0, kHuge).number("lm_rel_cost_tolerance", lm_rel_cost_tolerance, 0, 1);
  c.number("lm_step_tolerance", lm_step_tolerance, 0, 1).number("lm_chi2_tolerance", lm_chi2_tolerance, 0, kHuge);
  c.number("jacobian_relative_step", jacobian_relative_step, 0, 0.1, true);
  c.number("lm_geodesic_step", lm_geodesic_step, 0, 1, true).number("lm_geodesic_alpha", lm_geodesic_alpha, 0, kHuge, true);
  c.number("tracking_misfit_ratio", tracking_misfit_ratio, 1, kHuge).number("tracking_misfit_slack", tracking_misfit_slack, 0, 1);
  c.count("tracking_give_up_iterations", tracking_give_up_iterations, 0);
  c.number("tracking_give_up_ratio", tracking_give_up_ratio, 0, kHuge, true);
  c.number("tracking_give_up_progress", tracking_give_up_progress, 0, 1);
  c.each("valley_stiffness_factors", valley_stiffness_factors, 0, kHuge, true);
  c.each("valley_force_factors", valley_force_factors, 0, kHuge, true);
  c.number("start_fit_period_fraction", start_fit_period_fraction, 0, 1, true);
  c.number("min_signal_scale_m", min_signal_scale_m, 0, 1, true).number("start_prior_floor_rel", start_prior_floor_rel, 0, 1);
  c.number("false_continuation_chi2", false_continuation_chi2, 0, kHuge, true);
  c.number("continuation_refuted_chi2", continuation_refuted_chi2, 0, kHuge);
  for (const auto& [name, drift] : parameter_drift_rel)
    c.number(("parameter_drift_rel." + name).c_str(), drift, 0, 10, true);
  c.number("pool_gate_chi2", pool_gate_chi2, 0, kHuge, true);
  c.count("pool_max_iterations", pool_max_iterations, 0);
  c.count("pool_gated_iterations", pool_gated_iterations, 0).number("pool_valley_chi2", pool_valley_chi2, 0, kHuge, true);
  c.count("max_coast_samples", max_coast_samples, 0).number("coast_grid_tolerance", coast_grid_tolerance, 0, 0.5);
  c.number("min_noise_rel", min_noise_rel, 0, 1).number("hac_max_lag_fraction", hac_max_lag_fraction, 0, 1);
  c.count("hac_max_lags", hac_max_lags, 0).number("max_misfit", max_misfit, 0, kHuge, true);
  c.number("singular_rel_eigenvalue", singular_rel_eigenvalue, 0, 1, false, true);
  c.number("undetermined_sigma_fraction", undetermined_sigma_fraction, 0, kHuge, true);
  c.number("trade_off_correlation", trade_off_correlation, 0, 1, true).number("at_bound_tolerance", at_bound_tolerance, 0, 0.5);
  c.number("bound_max_lag1", bound_max_lag1, 0, 1);
  c.number("search_contact_rad_per_substep", search_contact_rad_per_substep, 0, kHuge, true);
  c.number("search_crossing_rad_per_substep", search_crossing_rad_per_substep, 0, kHuge, true);
  return c.result();
}

}  // namespace tipforce
