#pragma once
#include <CLI/CLI.hpp>

namespace tipforce::cli {
// Registers `tipforce inspect` on the top-level app.
void add_inspect_command(CLI::App& app);
}  // namespace tipforce::cli
