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
      "max_indentation_m, dissipated_energy_j for dissipative models, misfit, status): NAME.png and NAME.pdf\n"
      "(viridis over the 1st-99th percentile, clipped pixels marked, colour bar in SI units with round ticks,\n"
      "axes in metres with a scale bar when the scan size is known, grey = no estimate) and NAME.gsf (float32,\n"
      "NaN = no estimate). h_m is shown as height -h: bright = high. estimates.csv (one row per estimate);\n"
      "latency_histogram and latency_over_time (when the estimates carry receive/publish times); with --truth,\n"
      "truth_PARAM.png/.pdf and the accuracy per parameter. Pixel (pixel_x, pixel_y) is column pixel_x, row\n"
      "pixel_y, row 0 at the top.");
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
  cmd->add_option("--pixel-size-m", opt->pixel_size_m, "Physical pixel size in metres (overrides the log's scan size)");
  auto scan_size = std::make_shared<std::vector<double>>();
  cmd->add_option("--scan-size-m", *scan_size, "Scan size X[,Y] in metres (overrides the log's scan size)")
      ->delimiter(',')->expected(1, 2);
  cmd->add_option("--scan-log", opt->scan_log,
                  "A log with the scan's scan_geometry_t (the windows log of tipforce import), when the estimates "
                  "log lacks it (tipforced's output)");
  cmd->add_option("--scan-channel", opt->scan_channel, "Channel of scan_geometry_t")->capture_default_str();
  cmd->callback([opt, scan_size, inputs] {
    opt->in = inputs->front();
    opt->more_in.assign(inputs->begin() + 1, inputs->end());
    if (!scan_size->empty()) {
      opt->scan_size_x_m = (*scan_size)[0];
      opt->scan_size_y_m = scan_size->size() > 1 ? (*scan_size)[1] : 0;
    }
    tipforce::map::MapReport report;
    try {
      report = tipforce::map::run_map(*opt, std::cout);
    } catch (const tipforce::map::MapInputError& e) {
      std::cerr << "tipforce map: error: " << e.what() << "\n";
      throw CLI::RuntimeError(2);
    } catch (const tipforce::map::MapDamagedError& e) {
      for (const auto& line : e.damage()) std::cerr << "tipforce map: " << line << "\n";
      std::cerr << "tipforce map: error: " << e.what() << "\n";
      throw CLI::RuntimeError(3);
    } catch (const tipforce::map::MapError& e) {
      std::cerr << "tipforce map: error: " << e.what() << "\n";
      throw CLI::RuntimeError(1);
    } catch (const std::exception& e) {
      std::cerr << "tipforce map: error: " << opt->in << ": " << e.what() << "\n";
      throw CLI::RuntimeError(1);
    }
    // As tipforce invert and tipforced: a damaged log is read around, said on stderr (the summary
    // may go to a file) and exit 3, so that a map of part of a scan is not taken for the whole.
    if (report.damaged_stretches > 0) {
      const bool one_log = opt->more_in.empty();  // several logs' lines name their file already
      for (const auto& line : report.damage)
        std::cerr << "tipforce map: " << (one_log ? opt->in + ": " : "") << line << "\n";
      std::cerr << "tipforce map: the input is damaged (" << report.damaged_stretches << " damaged stretch"
                << (report.damaged_stretches == 1 ? "" : "es") << " skipped); the maps hold every estimate that could be read, and "
                << report.missing.size() << " of their " << report.width << " x " << report.height
                << " pixels have none\n";
      std::cout.flush();
      throw CLI::RuntimeError(3);
    }
  });
}
}  // namespace tipforce::cli
