#include "map_command.hpp"

#include <exception>
#include <iostream>
#include <memory>

#include "map_error.hpp"
#include "map_run.hpp"

namespace tipforce::cli {
void add_map_command(CLI::App& app) {
  auto opt = std::make_shared<tipforce::map::MapOptions>();
  auto* cmd = app.add_subcommand("map", "Force maps (PNG + Gwyddion .gsf), a CSV table and latency plots from an estimates log");
  cmd->footer(
      "Writes into --out, per quantity (each estimated parameter, its _sigma, peak_force_n, mean_force_n,\n"
      "max_indentation_m, dissipated_energy_j, misfit, status): NAME.png (viridis, colour bar in SI units with\n"
      "a prefix, grey = no estimate; rejected windows count as no estimate) and NAME.gsf (float32, NaN = no\n"
      "estimate); estimates.csv (one row per estimate); latency_histogram.png and latency_over_time.png (when\n"
      "the estimates carry receive/publish times); with --truth, truth_PARAM.png and the accuracy per parameter.\n"
      "Pixel (pixel_x, pixel_y) is column pixel_x, row pixel_y, row 0 at the top.");
  auto inputs = std::make_shared<std::vector<std::string>>();
  cmd->add_option("--in", *inputs,
                  "LCM log holding force_estimate_t (and latency_stats_t) messages; several (--in A --in B, or "
                  "--in A B) are mapped as one: the logs of the shards of a sharded run")
      ->required();
  cmd->add_option("--out", opt->out, "Output directory (created if missing)")->required();
  cmd->add_option("--probe", opt->probe, "Map this probe's estimates (needed when the log holds several probes)");
  cmd->add_option("--truth", opt->truth,
                  "Truth CSV of `tipforce simulate` (seq,pixel_x,pixel_y,<param>...): comparison images and accuracy");
  cmd->add_option("--channel", opt->channel, "Estimate channel")->capture_default_str();
  cmd->add_option("--stats-channel", opt->stats_channel, "Latency statistics channel")->capture_default_str();
  cmd->add_option("--pixel-size-m", opt->pixel_size_m,
                  "Physical pixel size in metres for the .gsf files (XReal = XRes * size); default 1e-7 m = 100 nm")
      ->capture_default_str();
  cmd->callback([opt, inputs] {
    opt->in = inputs->front();
    opt->more_in.assign(inputs->begin() + 1, inputs->end());
    try {
      tipforce::map::run_map(*opt, std::cout);
    } catch (const tipforce::map::MapError& e) {
      std::cerr << "tipforce map: error: " << e.what() << "\n";
      throw CLI::RuntimeError(1);
    } catch (const std::exception& e) {
      std::cerr << "tipforce map: error: " << opt->in << ": " << e.what() << "\n";
      throw CLI::RuntimeError(1);
    }
  });
}
}  // namespace tipforce::cli
