#pragma once
// The global search: a bounded particle swarm (PSO with Clerc's constriction) in the normalised
// coordinates, scoring each generation in one batch through a BatchCost.
#include <limits>
#include <random>
#include <span>
#include <vector>

#include "inversion/coordinates.hpp"
#include "inversion/deadline.hpp"
#include "tipforce/inversion.hpp"

namespace tipforce::inversion {

// Scores a batch of candidates (lower is better; infinity where one cannot be scored).
class BatchCost {
 public:
  virtual ~BatchCost() = default;
  virtual std::vector<double> costs(std::span<const Point> points) = 0;
};

// The best point so far and its cost; the swarm replaces it only by a better one.
struct Incumbent {
  Point point;
  double cost = std::numeric_limits<double>::infinity();
};

// Where the particles begin.
struct SwarmSeeding {
  int particles = 4;
  int generations = 1;
  // Warm: the previous estimate (normalised) and the spread around it, per unknown; empty: cold.
  std::vector<double> centre, spread;
  // Cold: which unknown is h (-1: none) and the tip's reach in its normalised coordinate.
  int reach_index = -1;
  double reach_unit = 0;
};

// Warm: particle 0 at the centre, particles 1 .. P/2 - 1 Gaussian around it (the spread as its
// standard deviation), the rest stratified over the bounds. Cold: stratified along each axis,
// every options.reach_particle_every-th particle with h at the reach. Then Clerc's constriction
// until seeding.generations or options.stall_generations without a gain of stall_rel_tolerance.
struct SwarmOutcome {
  int generations = 0;  // run, the first (scoring the seeds) included
  bool cut_short = false;  // stopped at the deadline, checked before each generation
};
SwarmOutcome run_swarm(BatchCost& cost, int n_unknowns, const SwarmSeeding& seeding, const InversionOptions& options,
                       std::mt19937_64& rng, Incumbent& best, const Deadline& deadline = Deadline());

}  // namespace tipforce::inversion
