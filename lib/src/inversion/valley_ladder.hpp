#pragma once
// The candidates of a changed pixel along the k-h valley (WindowSolver::valley_start): which
// factors of the previous estimate to try, as a grid of rungs, and where to look once the grid's
// costs are known. Only factors here; the window solver turns each rung into a point (the
// stiffness-like unknown scaled, h placed for the force).
#include <span>
#include <vector>

namespace tipforce::inversion {

struct ValleyRung {
  int unknown = 0;                 // the stiffness-like unknown scaled (index among the unknowns)
  double stiffness_factor = 1.0;   // on that unknown's previous value
  double force_factor = 1.0;       // on the previous peak force, which places h
};

// Every unknown of `stiffness_unknowns` times every stiffness factor, each with every force factor;
// a stiffness factor of 1 (the previous estimate unscaled) only for the first unknown.
std::vector<ValleyRung> valley_grid(std::span<const int> stiffness_unknowns, std::span<const double> stiffness_factors,
                                    std::span<const double> force_factors);

// Where the grid's best rung and its neighbours point (costs: one per grid rung, in order), per
// ladder in log factor: between two neighbours, the vertex of the parabola through the three
// (clamped to them); at a ladder's end, beyond it: one rung's ratio further for the stiffness,
// one and two for the force (the peak force at a domain edge moves by more than the stiffness
// ladder's force rungs span: bench's 1 -> 4 N/m edge 2.8 x). The rungs: each ladder's answers
// with the other ladder at the best rung, and both vertices together where both ladders have one;
// none where the best cost is not finite. A ladder that is not ascending and positive gives
// only its best rung. Neighbours are taken at their nominal factors, also where the stiffness
// was clamped to its bounds (two rungs then the same point, their costs equal: the vertex lies
// between them and is clamped again in the window solver).
std::vector<ValleyRung> valley_refinement(std::span<const ValleyRung> grid, std::span<const double> costs,
                                          std::span<const double> stiffness_factors,
                                          std::span<const double> force_factors);

// The vertex of the parabola through (x_lo, c_lo), (x, c), (x_hi, c_hi), x_lo < x < x_hi, clamped
// to [x_lo, x_hi]; x where the three do not bend upwards.
double parabola_vertex(double x_lo, double c_lo, double x, double c, double x_hi, double c_hi);

}  // namespace tipforce::inversion
