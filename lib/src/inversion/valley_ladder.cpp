#include "inversion/valley_ladder.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>
#include <utility>

namespace tipforce::inversion {

std::vector<ValleyRung> valley_grid(std::span<const int> stiffness_unknowns, std::span<const double> stiffness_factors,
                                    std::span<const double> force_factors) {
  std::vector<ValleyRung> grid;
  bool unscaled = false;
  for (int j : stiffness_unknowns)
    for (double f : stiffness_factors) {
      if (f == 1.0 && std::exchange(unscaled, true)) continue;
      for (double g : force_factors) grid.push_back({j, f, g});
    }
  return grid;
}

double parabola_vertex(double x_lo, double c_lo, double x, double c, double x_hi, double c_hi) {
  const double d1 = x - x_lo, d2 = x_hi - x;
  // Second divided difference times d1 d2 (d1 + d2) / 2: positive when the three bend upwards.
  const double bend = d2 * (c_lo - c) + d1 * (c_hi - c);
  if (!(bend > 0) || !std::isfinite(bend)) return x;
  const double v = x + 0.5 * (d2 * d2 * (c_lo - c) - d1 * d1 * (c_hi - c)) / bend;
  return std::clamp(v, x_lo, x_hi);
}

namespace {

// One ladder's answers at rung i of `ladder` (ascending, positive), given the cost at rung k
// (nullopt: that rung is not in the grid or its cost is not finite): between neighbours the
// parabola's vertex (vertex true), at an end rungs_beyond rungs outwards, else the rung itself.
struct LadderAnswer {
  std::vector<double> values;
  bool vertex = false;
};

template <class CostAt>
LadderAnswer ladder_answers(std::span<const double> ladder, std::size_t i, double best_cost, CostAt cost_at,
                            int rungs_beyond) {
  const std::size_t n = ladder.size();
  bool usable = n >= 2 && ladder[0] > 0;
  for (std::size_t k = 1; usable && k < n; ++k) usable = ladder[k] > ladder[k - 1];
  if (!usable) return {{ladder[i]}, false};
  if (i > 0 && i + 1 < n) {
    const std::optional<double> lo = cost_at(i - 1), hi = cost_at(i + 1);
    if (!lo || !hi) return {{ladder[i]}, false};
    const double x = std::log(ladder[i]);
    const double v = parabola_vertex(std::log(ladder[i - 1]), *lo, x, best_cost, std::log(ladder[i + 1]), *hi);
    return v == x ? LadderAnswer{{ladder[i]}, false} : LadderAnswer{{std::exp(v)}, true};
  }
  // At an end: the ladder's ratio there, continued outwards.
  const double ratio = i == 0 ? ladder[0] / ladder[1] : ladder[n - 1] / ladder[n - 2];
  LadderAnswer beyond;
  double v = ladder[i];
  for (int r = 0; r < rungs_beyond; ++r) beyond.values.push_back(v *= ratio);
  return beyond;
}

}  // namespace

std::vector<ValleyRung> valley_refinement(std::span<const ValleyRung> grid, std::span<const double> costs,
                                          std::span<const double> stiffness_factors,
                                          std::span<const double> force_factors) {
  if (grid.empty() || costs.size() != grid.size()) return {};
  const auto b = static_cast<std::size_t>(std::min_element(costs.begin(), costs.end()) - costs.begin());
  if (!std::isfinite(costs[b])) return {};
  const ValleyRung best = grid[b];
  auto index_of = [](std::span<const double> ladder, double v) {
    return static_cast<std::size_t>(std::find(ladder.begin(), ladder.end(), v) - ladder.begin());
  };
  const std::size_t fi = index_of(stiffness_factors, best.stiffness_factor);
  const std::size_t gi = index_of(force_factors, best.force_factor);
  if (fi >= stiffness_factors.size() || gi >= force_factors.size()) return {};
  auto cost_of = [&](double f, double g) -> std::optional<double> {
    for (std::size_t k = 0; k < grid.size(); ++k)
      // The unscaled rung is the same point whichever unknown it was listed under.
      if ((grid[k].unknown == best.unknown || f == 1.0) && grid[k].stiffness_factor == f && grid[k].force_factor == g &&
          std::isfinite(costs[k]))
        return costs[k];
    return std::nullopt;
  };
  const LadderAnswer fs = ladder_answers(
      stiffness_factors, fi, costs[b], [&](std::size_t k) { return cost_of(stiffness_factors[k], best.force_factor); }, 1);
  const LadderAnswer gs = ladder_answers(
      force_factors, gi, costs[b], [&](std::size_t k) { return cost_of(best.stiffness_factor, force_factors[k]); }, 2);
  // Each ladder's answers with the other at the best rung, and the two vertices together where
  // both ladders have one: at a ladder's end the other's rung is more likely just too short
  // (bench's 1 -> 4 N/m edge: the best at stiffness x 4 and force x 1.4, the answer at x 4 and
  // x 2.8), and stepping both outwards at once left the valley.
  std::vector<ValleyRung> out;
  auto add = [&](double f, double g) {
    if (f != best.stiffness_factor || g != best.force_factor) out.push_back({best.unknown, f, g});
  };
  for (double f : fs.values) add(f, best.force_factor);
  for (double g : gs.values) add(best.stiffness_factor, g);
  if (fs.vertex && gs.vertex) add(fs.values[0], gs.values[0]);
  return out;
}

}  // namespace tipforce::inversion
