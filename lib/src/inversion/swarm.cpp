#include "inversion/swarm.hpp"

#include <algorithm>

namespace tipforce::inversion {
namespace {

// Stratification: particle p's cell along axis j is p (2j + 1) 7919 mod P, a permutation of the
// cells that differs between axes (7919 is a prime that shares no factor with any swarm size up
// to 1000), so that the particles cover each axis evenly without lying on one diagonal.
constexpr int kStratificationPrime = 7919;

struct Swarm {
  std::vector<Point> position, personal_best;
  std::vector<double> personal_cost;
  std::vector<std::vector<double>> velocity;
};

Swarm seed_particles(int m, const SwarmSeeding& s, const InversionOptions& opt, std::mt19937_64& rng) {
  const int P = s.particles;
  const bool warm = !s.centre.empty();
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  std::normal_distribution<double> gauss(0.0, 1.0);
  Swarm sw;
  sw.position.resize(static_cast<std::size_t>(P));
  sw.velocity.assign(static_cast<std::size_t>(P), std::vector<double>(static_cast<std::size_t>(m)));
  for (int p = 0; p < P; ++p) {
    sw.position[p].x.resize(static_cast<std::size_t>(m));
    for (int j = 0; j < m; ++j) {
      double& x = sw.position[p].x[j];
      if (warm && p == 0) x = s.centre[j];
      else if (warm && p < P / 2) x = clamp01(s.centre[j] + s.spread[j] * gauss(rng));
      else if (j == s.reach_index && p % opt.reach_particle_every == 0) x = s.reach_unit;
      else x = (((p * (2 * j + 1) * kStratificationPrime) % P) + uni(rng)) / P;
      sw.velocity[p][j] = opt.swarm_initial_velocity * (uni(rng) - 0.5);
    }
  }
  return sw;
}

// Particle p's and the incumbent's update from a generation's costs.
void take_costs(Swarm& sw, const std::vector<double>& cost, Incumbent& best) {
  for (std::size_t p = 0; p < sw.position.size(); ++p) {
    if (cost[p] < sw.personal_cost[p]) {
      sw.personal_cost[p] = cost[p];
      sw.personal_best[p] = sw.position[p];
    }
    if (cost[p] < best.cost) {
      best.cost = cost[p];
      best.point = sw.position[p];
    }
  }
}

void move_particles(Swarm& sw, const Incumbent& best, const InversionOptions& opt, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  const double w = opt.swarm_inertia, c = opt.swarm_acceleration;
  for (std::size_t p = 0; p < sw.position.size(); ++p)
    for (std::size_t j = 0; j < sw.position[p].x.size(); ++j) {
      double& v = sw.velocity[p][j];
      double& x = sw.position[p].x[j];
      // Drawn in a fixed order (two draws in one expression are unsequenced in C++).
      const double r_personal = uni(rng), r_global = uni(rng);
      v = w * v + c * r_personal * (sw.personal_best[p].x[j] - x) + c * r_global * (best.point.x[j] - x);
      v = std::clamp(v, -opt.swarm_max_velocity, opt.swarm_max_velocity);
      double next = x + v;
      if (next < 0 || next > 1) {
        next = clamp01(next);
        v = -opt.swarm_wall_restitution * v;
      }
      x = next;
    }
}

}  // namespace

SwarmOutcome run_swarm(BatchCost& cost, int m, const SwarmSeeding& seeding, const InversionOptions& opt,
                       std::mt19937_64& rng, Incumbent& best, const Deadline& deadline) {
  SwarmOutcome out;
  if (deadline.passed()) {
    out.cut_short = true;
    return out;
  }
  Swarm sw = seed_particles(m, seeding, opt, rng);
  sw.personal_best = sw.position;
  sw.personal_cost = cost.costs(sw.position);
  for (int p = 0; p < seeding.particles; ++p)
    if (sw.personal_cost[p] < best.cost) {
      best.cost = sw.personal_cost[p];
      best.point = sw.position[p];
    }
  int stall = 0, gen = 0;
  for (gen = 1; gen < seeding.generations && stall < opt.stall_generations; ++gen) {
    if (deadline.passed()) {
      out.cut_short = true;
      break;
    }
    move_particles(sw, best, opt, rng);
    const std::vector<double> c = cost.costs(sw.position);
    const double before = best.cost;
    take_costs(sw, c, best);
    stall = (before - best.cost > opt.stall_rel_tolerance * before) ? 0 : stall + 1;
  }
  out.generations = gen;
  return out;
}

}  // namespace tipforce::inversion
