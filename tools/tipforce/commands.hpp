#pragma once
#include <CLI/CLI.hpp>

namespace tipforce::cli {
void add_modes_command(CLI::App& app);
void add_simulate_command(CLI::App& app);
void add_invert_command(CLI::App& app);
void add_bench_command(CLI::App& app);
}  // namespace tipforce::cli
