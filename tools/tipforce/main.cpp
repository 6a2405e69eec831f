// tipforce: the command line for modal analysis, synthetic scans, offline inversion, maps and
// benchmarks.
#include <CLI/CLI.hpp>

#include <csignal>
#include <exception>
#include <iostream>

#include "commands.hpp"
#include "import_command.hpp"
#include "inspect_command.hpp"
#include "map_command.hpp"
#include "tipforce/process_memory.hpp"

int main(int argc, char** argv) {
  // A closed output pipe (`tipforce invert ... | head`) is a write error, not a death by SIGPIPE.
  std::signal(SIGPIPE, SIG_IGN);
  // invert, bench and inspect solve windows as tipforced does: their buffers reused, not faulted
  // in afresh (process_memory.hpp).
  tipforce::keep_freed_memory_in_process();
  CLI::App app{"tipforce " TIPFORCE_VERSION ": tip-sample force estimation for dynamic AFM"};
  app.set_version_flag("--version", TIPFORCE_VERSION);
  app.require_subcommand(1);
  tipforce::cli::add_modes_command(app);
  tipforce::cli::add_simulate_command(app);
  tipforce::cli::add_invert_command(app);
  tipforce::cli::add_bench_command(app);
  tipforce::cli::add_map_command(app);
  tipforce::cli::add_import_command(app);
  tipforce::cli::add_inspect_command(app);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    // A command's own outcome (1 output lost, 2 bad input, 3 damaged input) passes unchanged.
    // CLI11's parse errors carry its own codes (105, 106, 109, ...); the README promises 2 for
    // any usage error, so scripts can tell a typo from a damaged log. --help and --version: 0.
    const int code = app.exit(e);
    return code == 0 || e.get_name() == "RuntimeError" ? code : 2;
  } catch (const std::exception& e) {
    std::cerr << "tipforce: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
