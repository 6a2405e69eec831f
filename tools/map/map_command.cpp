#include "map_command.hpp"

#include <iostream>

namespace tipforce::cli {
void add_map_command(CLI::App& app) {
  auto* cmd = app.add_subcommand("map", "Force maps from an estimates log (not yet implemented)");
  cmd->callback([] {
    std::cerr << "tipforce map: not implemented yet\n";
    throw CLI::RuntimeError(2);
  });
}
}  // namespace tipforce::cli
