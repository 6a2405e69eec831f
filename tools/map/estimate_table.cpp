#include "estimate_table.hpp"

#include <cmath>
#include <fstream>

#include "map_error.hpp"
#include "map_grid.hpp"
#include "quantity.hpp"

namespace tipforce::map {
namespace {
// RFC 4180 quoting when needed.
std::string csv_field(const std::string& s) {
  if (s.find_first_of(",\"\n\r") == std::string::npos) return s;
  std::string out = "\"";
  for (char ch : s) {
    if (ch == '"') out += '"';
    out += ch;
  }
  return out + "\"";
}

std::string num(double v) { return std::isfinite(v) ? exact_number(v) : (std::isnan(v) ? "" : exact_number(v)); }
}  // namespace

std::string status_name(int status) {
  switch (status) {
    case tipforce::force_estimate_t::STATUS_OK: return "ok";
    case tipforce::force_estimate_t::STATUS_NOT_CONVERGED: return "not_converged";
    case tipforce::force_estimate_t::STATUS_REJECTED: return "rejected";
    default: return "unknown_" + std::to_string(status);
  }
}

void write_estimate_table(const std::string& path, const std::vector<tipforce::force_estimate_t>& estimates,
                          const std::vector<std::string>& param_names) {
  std::ofstream out(path, std::ios::trunc);
  if (!out) throw MapError("cannot write " + path);
  out << "utime,probe,seq,pixel_x,pixel_y,status,message,model";
  for (const auto& p : param_names) out << ',' << csv_field(p) << ',' << csv_field(p + "_sigma");
  out << ",misfit,peak_force_n,mean_force_n,max_indentation_m,dissipated_energy_j,iterations,forward_solves,"
         "receive_utime,publish_utime,latency_us\n";
  for (const auto& e : estimates) {
    out << e.utime << ',' << csv_field(e.probe) << ',' << e.seq << ',' << e.pixel_x << ',' << e.pixel_y << ','
        << status_name(e.status) << ',' << csv_field(e.message) << ',' << csv_field(e.model);
    for (const auto& p : param_names) out << ',' << num(param_value(e, p)) << ',' << num(param_value(e, p, true));
    out << ',' << num(e.misfit) << ',' << num(e.peak_force_n) << ',' << num(e.mean_force_n) << ','
        << num(e.max_indentation_m) << ',' << num(e.dissipated_energy_j) << ',' << e.iterations << ','
        << e.forward_solves << ',' << e.receive_utime << ',' << e.publish_utime << ',';
    if (e.receive_utime != 0 && e.publish_utime != 0) out << (e.publish_utime - e.receive_utime);
    out << '\n';
  }
  out.close();
  if (!out) throw MapError("cannot write " + path + " (disk full?)");
}
}  // namespace tipforce::map
