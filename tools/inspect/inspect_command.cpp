// The command line of `tipforce inspect`.
#include "inspect_command.hpp"

#include <filesystem>
#include <iostream>
#include <system_error>
#include <memory>

#include "inspect_run.hpp"
#include "map_error.hpp"

namespace tipforce::cli {

void add_inspect_command(CLI::App& app) {
  auto o = std::make_shared<tipforce::inspect::InspectOptions>();
  auto pixel = std::make_shared<std::vector<int>>();
  auto* cmd = app.add_subcommand("inspect", "One pixel's fit: deflection, force, force-distance, misfit landscape");
  cmd->footer(
      "Refits the window at --pixel X,Y (or takes its estimate from --estimates) and writes into --out:\n"
      "deflection (measured, fitted, residual), force_time, force_distance (force against the tip position\n"
      "relative to the surface h) and misfit_landscape (over the two most correlated unknowns, with the\n"
      "estimate and its 2-sigma ellipse), each as PNG and PDF; curves.csv, landscape.csv, estimate.csv.");
  cmd->add_option("--config", o->config, "Config file (TOML)")->required()->check(CLI::ExistingFile);
  cmd->add_option("--in", o->in, "LCM log with the windows")->required()->check(CLI::ExistingFile);
  cmd->add_option("--estimates", o->estimates, "LCM log with the estimates (else the pixel is refitted)")
      ->check(CLI::ExistingFile);
  cmd->add_option("--pixel", *pixel, "Pixel X,Y")->required()->delimiter(',')->expected(2);
  cmd->add_option("--probe", o->probe, "Probe (when several have a window at the pixel)");
  cmd->add_option("--out", o->out, "Output directory (created)")->required();
  cmd->callback([o, pixel] {
    o->pixel_x = (*pixel)[0];
    o->pixel_y = (*pixel)[1];
    std::error_code ec;
    const bool out_existed = std::filesystem::exists(o->out, ec);
    // A run that fails leaves no empty directory of its own making (remove() spares a full one).
    auto undo_out = [&] {
      if (!out_existed) std::filesystem::remove(o->out, ec);
    };
    try {
      tipforce::inspect::prepare_output_dir(*o);
      auto report = tipforce::inspect::run_inspect(*o, std::cout);
      tipforce::inspect::write_inspect_files(*o, report);
      std::cout << "files written to " << o->out << ":";
      for (const auto& f : report.files) std::cout << " " << f;
      std::cout << "\n";
    } catch (const tipforce::inspect::InspectDamagedError& e) {
      undo_out();
      std::cerr << "tipforce inspect: error: " << e.what() << "\n";
      throw CLI::RuntimeError(3);
    } catch (const tipforce::inspect::InspectError& e) {
      undo_out();
      std::cerr << "tipforce inspect: error: " << e.what() << "\n";
      throw CLI::RuntimeError(2);
    } catch (const tipforce::map::MapError& e) {
      undo_out();
      std::cerr << "tipforce inspect: error: " << e.what() << "\n";
      throw CLI::RuntimeError(1);
    }
  });
}

}  // namespace tipforce::cli
