#pragma once
// One window's inversion as a short driver over the stages (as Ceres's TrustRegionMinimizer
// drives its strategy): start and prior, tracking polish or swarm, the start shift's projection,
// the Levenberg-Marquardt polish, the pooling with the previous pixel (when configured), the
// covariance, the derived quantities, the report, and what the fit hands the next window.
#include <cmath>
#include <memory>
#include <optional>
#include <random>

#include "inversion/batch_evaluator.hpp"
#include "inversion/coordinates.hpp"
#include "inversion/covariance.hpp"
#include "inversion/deadline.hpp"
#include "inversion/levenberg_marquardt.hpp"
#include "inversion/parameter_prior.hpp"
#include "inversion/start_prior.hpp"
#include "inversion/start_projection.hpp"
#include "inversion/stream_state.hpp"
#include "inversion/swarm.hpp"
#include "inversion/valley_ladder.hpp"
#include "tipforce/inversion.hpp"

namespace tipforce::inversion {

// Whether an estimate can be trusted, and why not.
struct Verdict {
  EstimateStatus status = EstimateStatus::ok;
  std::string prefix;          // what goes before the covariance's notes in the message
  bool singular_only = false;  // not converged only because an unknown is undetermined
  bool cut_short = false;      // stopped at the deadline: never seeds the next window
};

// How to solve one window.
struct SolvePlan {
  InitialState start = InitialState::rest;  // as decided for the stream (continued: an end state exists)
  // Polish from these values only (no swarm): the continued hypothesis tried again at the
  // answer of a cold search (Inverter: a window whose start conflicts with the prior).
  std::optional<std::vector<double>> polish_from = std::nullopt;
  // A cold start's first candidate: the previous window's best so far, where the deadline cut its
  // fit short (PreviousFit::resume_values; the Inverter passes it on within a line only).
  std::optional<std::vector<double>> resume_from = std::nullopt;
  // The fit stops here (between batches) with the best so far, NOT_CONVERGED, the message
  // beginning with `deadline_what` (e.g. "deadline of 5 ms from receipt") and where it stopped.
  Deadline deadline = Deadline();
  std::string deadline_what;
};

class WindowSolver {
 public:
  // The window has passed window_problem().
  WindowSolver(const ProbeModel& probe, ForwardBackend& backend, StreamState& stream, const Window& window,
               SolvePlan plan);
  WindowSolver(const WindowSolver&) = delete;
  WindowSolver& operator=(const WindowSolver&) = delete;

  // Inverts the window; the stream state is left as it is (but for per-probe caches).
  Estimate solve();
  // The start-conflict chi-square at the answer (start_conflict_chi2; 0 without a start prior).
  double start_conflict() const { return start_conflict_; }
  bool cut_short() const { return verdict_.cut_short; }
  // The deadline came before the fit scored anything: the window was not fitted at all.
  bool skipped() const { return verdict_.cut_short && !std::isfinite(best_.cost); }
  // Hands the fit on to the next window (its end state, prior and warm start, as far as trusted).
  void hand_off();

 private:
  bool can_track() const;
  bool track();                 // true when the polish from the previous estimate fits as well as it did
  struct PhysicsGrid {
    std::vector<Point> points;
    long per_cell = 1;  // h values per cell of the other unknowns
    int polishes = 1;   // cells polished at most (InversionOptions::cold_physics_polishes*)
    double second_ratio = 1.0;  // ... a later one only within this factor of the best's cost
  };
  struct SurfaceBelowReach {
    int ih;          // h's index among the unknowns
    double reach_m;  // the tip's highest position in the window
  };
  std::optional<SurfaceBelowReach> surface_below_reach() const;
  std::optional<PhysicsGrid> physics_grid() const;
  bool polish_best_cells(const PhysicsGrid& grid, Incumbent& winner, Linearisation& winner_lin);
  std::vector<double> grid_costs(std::span<const Point> points);
  bool resume();                // a free start polished from SolvePlan::resume_from; false: not accepted
  bool physics_start();         // a free start from the window's physics, polished; false: swarm
  bool cold_answer_accepted() const;  // the free start's polish explains the window (physics_start)
  void forget_free_start(int iterations_before);  // ... and undone where it does not
  void start_at(const std::vector<double>& values);  // best_ at these values, not scored
  void score_by_trajectory();  // best_.cost from trajectory_ solved at best_ (scored_at_ says where)
  bool polish_giving_up(const char* stage, double limit);  // the polish, given up above ratio x limit
  bool continuation_refuted() const;  // the tracked answer's start conflict is beyond any edge's
  bool conflict_beyond_refutation() const;  // ... at best_, by lin_ (with a prior; 0 = never)
  bool continuation_explains_nothing(double best_valley_cost) const;  // refuted before the valley's polish
  bool refuted_at_the_given_values();  // ... and the same at SolvePlan::polish_from, linearised
  double refuted_chi2() const;          // the start conflict beyond which both refute
  double conflict_at_best() const;      // start_conflict_chi2 at best_, by lin_
  bool valley_start();          // a changed pixel: candidates along the k-h valley, polished
  std::vector<Point> valley_points(std::span<const ValleyRung> rungs, const SurfaceBelowReach& surface) const;
  std::vector<Point> valley_refinement_points(std::span<const ValleyRung> grid, std::span<const double> costs,
                                              const SurfaceBelowReach& surface) const;
  double depth_for_force(std::vector<double> values, int ih, double z_m, double force_n, double max_depth_m) const;
  bool edge_search();           // a continued window at an edge: the physics grid, start continued
  double tracking_limit() const;         // the misfit a tracked window must reach
  bool tracking_fit(double cost) const;  // ... and whether this cost reaches it
  bool every_unknown_moves_the_signal() const;  // at lin_: no Jacobian column of an unknown is zero
  bool at_a_bound() const;  // best_ has an unknown at its bound (within at_bound_tolerance)
  void search();                // the swarm, warm or cold
  // The Levenberg-Marquardt polish from best_; true when it gave up (PolishSettings::give_up_after).
  bool polish(const char* stage = "in the polish", int give_up_after = 0, double give_up_data_cost = 0,
              double give_up_progress = 1.0);
  // With a parameter prior: this window's answer pooled with the previous pixel's (a Kalman step,
  // then polished with the joint prior), unless the two disagree beyond pool_gate_chi2 (an edge)
  // by the innovation measured on the model at the pooled answer, the start conflicts with its
  // prior (the Inverter searches the window again), or the deadline passes first (the window's
  // own answer stands, with a note). A window beyond the gate by its linearisation gets a second
  // chance from the previous pixel's parameters (pool_gated_iterations, pool_valley_chi2).
  void pool();
  // The window's own answer, kept while pooling tries the joint prior.
  struct OwnAnswer {
    Incumbent incumbent;
    Linearisation lin;
    Eigen::VectorXd v;  // packed
  };
  std::optional<double> pool_from(const ParameterPrior& prior, const Eigen::VectorXd& kalman, const OwnAnswer& own);
  std::optional<double> pool_across_the_valley(ParameterPrior& prior, const OwnAnswer& own);
  // The polish with the joint prior from packed v0; none when the deadline cut it (pooling_note_
  // says so, and the window's own answer stands).
  std::optional<PolishResult> pooled_polish(const ParameterPrior& prior, const Eigen::VectorXd& v0, int iterations);
  // pooled_innovation_chi2 of the pooled polish's answer r against the window's own.
  double innovation_on_the_model(const PolishResult& r, const OwnAnswer& own) const;
  // The Kalman step from this window's own answer (the prior widened by an innovation above its
  // expectation); none beyond the gate (pooling_note_ says so). innovation_chi2: the linear
  // innovation, NaN where it was not measured.
  std::optional<Eigen::VectorXd> kalman_point(ParameterPrior& prior, double& innovation_chi2);
  // True (and cut_ says where) once the deadline has passed; checked before each stage's batches.
  bool out_of_time(const std::string& where);
  std::string outside_the_bounds() const;  // a note when the answer is pinned at a bound by data beyond it
  Estimate report() const;
  double misfit(double cost) const { return energy_ > 0 ? std::sqrt(cost / energy_) : std::sqrt(cost); }
  // The residual variance per sample that the forward model's own error explains (min_noise_rel).
  double min_noise_var() const { return options_.min_noise_rel * options_.min_noise_rel * energy_ / N_; }
  std::vector<double> widths() const;

  const ProbeModel& probe_;
  const InversionOptions& options_;
  StreamState& stream_;
  const Window& window_;
  const SolvePlan plan_;
  const int m_, N_;
  double energy_ = 0;            // sum of the squared samples
  ModalState start_;             // the start before shifts
  Coordinates coordinates_;
  StartPrior prior_;
  std::optional<ParameterPrior> parameter_prior_;  // pooling: the previous pixel's parameters
  std::optional<StartPrior> pooled_prior_;          // prior_ with them, once this window pooled
  std::string pooling_note_;                        // why it did not, where it had the prior
  int decay_solves_ = 0;         // forward solves of the free-decay basis (when computed)
  std::optional<StartProjection> projection_;  // a free start without a prior
  ForwardBackend& backend_;
  BatchEvaluator evaluator_;
  int head_solves_ = 0;  // solves of the window's head (grid_costs), counted in forward_solves
  std::mt19937_64 rng_;          // the swarm's, seeded from the probe's seed and the window alone
  Incumbent best_;
  Linearisation lin_;
  int iterations_ = 0;
  bool last_polish_complete_ = false;  // the last polish neither gave up nor was cut short
  bool refuted_by_the_valley_ = false;  // continuation_explains_nothing held at the valley's grid
  bool tracked_ = false;
  std::string cut_;  // where the deadline stopped the fit; empty: it did not
  // The answer, kept for hand_off.
  double start_conflict_ = 0;
  Uncertainty uncertainty_;
  Trajectory trajectory_;
  std::optional<Point> scored_at_;  // where trajectory_ was solved before the answer (score_by_trajectory)
  Verdict verdict_;
  Estimate estimate_;
};

}  // namespace tipforce::inversion
