#pragma once
#include <CLI/CLI.hpp>

namespace tipforce::cli {
// Registers `tipforce import` on the top-level app.
void add_import_command(CLI::App& app);
}  // namespace tipforce::cli
