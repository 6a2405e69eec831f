// The CPU block solve for AVX2 + FMA (x86-64-v3; lib/CMakeLists.txt sets -march): cpu_step.hpp.
#include "cpu_step_impl.hpp"

namespace tipforce::cpu {
void solve_block_x86_64_v3(BlockJob& job) { solve_block_here(job); }
void lag_products_x86_64_v3(const double* r, int n, int lags, double* out) { lag_products_here(r, n, lags, out); }
}  // namespace tipforce::cpu
