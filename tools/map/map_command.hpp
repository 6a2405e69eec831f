#pragma once
#include <CLI/CLI.hpp>

namespace tipforce::cli {
// Registers `tipforce map` on the top-level app.
void add_map_command(CLI::App& app);
}  // namespace tipforce::cli
