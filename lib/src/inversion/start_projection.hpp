#pragma once
// Variable projection of a free start (Golub and Pereyra): the signal is (nearly) linear in the
// initial state of modes 1-2, so a candidate's parameters are scored by the residual left after
// the best such shift, i.e. with the free-decay responses projected out. Otherwise a start that
// is a little off sends the swarm to a wrong basin that the polish cannot leave.
#include <span>
#include <vector>

#include <Eigen/Dense>

#include "inversion/batch_evaluator.hpp"
#include "inversion/swarm.hpp"

namespace tipforce::inversion {

class StartProjection {
 public:
  // unit_decay: BatchEvaluator::unit_free_decay for the window; scaled here to its coordinates.
  StartProjection(const Eigen::MatrixXd& unit_decay, const Coordinates& coordinates);

  // The cost left after the best start shift, from a point's cost and its residual.
  double projected_cost(double cost, const Eigen::VectorXd& residual) const;
  // The best start shift (scaled coordinates, q and v of each mode interleaved) for a residual.
  Eigen::VectorXd best_shift(const Eigen::VectorXd& residual) const;

 private:
  Eigen::MatrixXd decay_;  // N x n_start_block: response to a unit (scaled) shift
  Eigen::MatrixXd basis_;  // orthonormal basis of its columns
};

// The swarm's cost: the window's misfit at the search resolution, projected when there is a
// projection (a free start without a prior), plain otherwise.
class SearchCost : public BatchCost {
 public:
  SearchCost(BatchEvaluator& evaluator, const Window& window, const StartProjection* projection)
      : evaluator_(evaluator), window_(window), projection_(projection) {}
  std::vector<double> costs(std::span<const Point> points) override;

 private:
  BatchEvaluator& evaluator_;
  const Window& window_;
  const StartProjection* projection_;
};

// The polish's start after the swarm: the incumbent with the best start shift for its residual,
// where that lowers the cost (at the accurate resolution); the cost of what is returned in `cost`.
Point with_best_start_shift(BatchEvaluator& evaluator, const Window& window, const StartProjection& projection,
                            const Point& incumbent, double& cost);

}  // namespace tipforce::inversion
