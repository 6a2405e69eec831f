#pragma once
// The one place the inversion calls the forward solver (ForwardBackend): every other stage asks
// this one for costs, signals, Jacobians or trajectories. A later switch of the Jacobian from
// finite differences to forward sensitivities changes linearise() and nothing else.
#include <span>
#include <limits>
#include <vector>

#include <Eigen/Dense>

#include "inversion/coordinates.hpp"
#include "tipforce/forward.hpp"
#include "tipforce/inversion.hpp"

namespace tipforce::inversion {

struct Evaluation {
  std::vector<double> cost;    // per point: sum of squared residuals; infinity where not finite
  std::vector<double> signal;  // [point * N + n], when asked for
};

enum class Resolution {
  accurate,  // the model's default contact resolution: the polish, the covariance
  search,    // coarse contact steps (InversionOptions::search_contact_rad_per_substep): the swarm
};

// What the final solve at the estimate gives.
struct Trajectory {
  std::vector<double> full;  // the full parameter vector
  std::vector<double> force_n, tip_z_m;
  ModalState end_state;
  double cost = std::numeric_limits<double>::quiet_NaN();  // its sum of squared residuals (infinity: not finite)
};

// The residual and Jacobian of the window's signal at one point, in packed coordinates.
struct Linearisation {
  // Where: the point, and its own solve's force, tip position and end state (the estimate's
  // trajectory when the polish ends here, without another solve).
  Point point;
  Trajectory at;
  Eigen::VectorXd r;      // data - model, per sample
  Eigen::MatrixXd J;      // d model / d packed: N x n_packed
  // d(end state of the start modes: q, v interleaved) / d packed, from the same sets: how the
  // state the next window inherits depends on this window's unknowns.
  Eigen::MatrixXd J_end;  // n_start_block x n_packed
};

class BatchEvaluator {
 public:
  // The window's start state before shifts; the references must outlive the evaluator.
  BatchEvaluator(ForwardBackend& backend, const ModalModel& modal, const ParameterSpace& space,
                 const StepCoefficients& step, const Window& window, const Coordinates& coordinates,
                 const ModalState& start, const InversionOptions& options);

  // One batch: the cost of each point (and its signal when asked).
  // sets_per_block: ForwardBatch::sets_per_block (0: the backend's choice).
  Evaluation evaluate(std::span<const Point> points, bool want_signal, Resolution resolution = Resolution::accurate,
                      int sets_per_block = 0);

  // Residual, forward-difference Jacobian and end-state sensitivities at p, in one batch; returns
  // the cost at p.
  double linearise(const Point& p, Linearisation& lin);

  // The solve at the estimate: force, tip position and the end state the next window inherits.
  Trajectory trajectory(const Point& p);
  // The full parameters at p, with nothing solved (no force, tip or end state): the estimate of a
  // window that the deadline left unfitted, which has no trajectory worth a solve.
  Trajectory unsolved(const Point& p) const;

  int forward_solves() const { return forward_solves_; }

  // The free decay of the signal from unit shifts of the start modes (q by 1 m, v by 1 m/s per
  // column, modes interleaved), N samples: no force, no drive. It depends on the window's length
  // and sample period only, so the caller keeps it. Counts its solves into forward_solves.
  static Eigen::MatrixXd unit_free_decay(ForwardBackend& backend, const ModalModel& modal, const StepCoefficients& step,
                                         int n_samples, double sample_period_s, int& forward_solves);

  // The state after `n_samples` sample periods from `from` at t0_s with the full parameters
  // `full` and no contact data (the window in between was lost): a coast across a gap.
  static ModalState coast(ForwardBackend& backend, const ModalModel& modal, const ParameterSpace& space,
                          const StepCoefficients& step, std::span<const double> full, const ModalState& from,
                          double t0_s, double sample_period_s, long n_samples);

 private:
  Evaluation evaluate_sets(std::span<const Point> points, bool want_signal, bool want_end_state, Resolution resolution,
                           int sets_per_block = 0, bool want_force = false);
  // A Jacobian's columns per block with their copy of the point: the CPU's widest block is 8.
  static constexpr int kMaxColumnsPerGroup = 7;

  ForwardBackend& backend_;
  const ParameterSpace& space_;
  const Window& window_;
  const Coordinates& coordinates_;
  const ModalState start_;
  const double relative_step_;
  ForwardProblem problem_, search_problem_;
  ForwardOutput out_;
  int forward_solves_ = 0;
};

}  // namespace tipforce::inversion
