// The CPU block solve for the x86-64 baseline (or the building machine's -march=native, or any
// other architecture): cpu_step.hpp.
#include "cpu_step_impl.hpp"

namespace tipforce::cpu {
void solve_block_baseline(BlockJob& job) { solve_block_here(job); }
}  // namespace tipforce::cpu
