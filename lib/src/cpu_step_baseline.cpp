// The CPU block solve for the x86-64 baseline (or the building machine's -march=native, or any
// other architecture): cpu_step.hpp.
#include "cpu_step_impl.hpp"

namespace tipforce::cpu {
void solve_block_baseline(BlockJob& job) { solve_block_here(job); }
void lag_products_baseline(const double* r, int n, int lags, double* out) { lag_products_here(r, n, lags, out); }
}  // namespace tipforce::cpu
