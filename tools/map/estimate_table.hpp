#pragma once
#include <string>
#include <vector>

#include <tipforce/force_estimate_t.hpp>

namespace tipforce::map {
// estimates.csv: one row per estimate message, in log order. Columns: utime, probe, seq,
// pixel_x, pixel_y, status, message, model, then for each parameter name (union over the
// estimates, first-seen order) NAME and NAME_sigma, then misfit, peak_force_n, mean_force_n,
// max_indentation_m, dissipated_energy_j, iterations, forward_solves, receive_utime,
// publish_utime, latency_us (publish - receive; empty when either is 0). A parameter an
// estimate lacks is an empty cell. Status is written as its name: ok, not_converged, rejected.
// Throws MapError naming the file when it cannot write.
void write_estimate_table(const std::string& path, const std::vector<tipforce::force_estimate_t>& estimates,
                          const std::vector<std::string>& param_names);

std::string status_name(int status);
}  // namespace tipforce::map
