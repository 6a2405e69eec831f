#include "inversion/window_solver.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <sstream>
#include <utility>

#include "inversion/derived_quantities.hpp"
#include "inversion/levenberg_marquardt.hpp"
#include "inversion/start_estimate.hpp"
#include "inversion/valley_ladder.hpp"
#include "tipforce/assert.hpp"
#include "tipforce/force_model.hpp"
#include "tipforce/parameter_layout.hpp"

namespace tipforce::inversion {
namespace {

// The residual's lag-1 autocorrelation: 0 +- 1/sqrt(N) for white noise, near 1 for the smooth
// structure a wrong model leaves.
double lag1_autocorrelation(const Eigen::VectorXd& r) {
  double lag0 = 0, lag1 = 0;
  for (Eigen::Index i = 0; i + 1 < r.size(); ++i) lag1 += r(i) * r(i + 1);
  for (Eigen::Index i = 0; i < r.size(); ++i) lag0 += r(i) * r(i);
  return lag0 > 0 ? lag1 / lag0 : 0.0;
}

double sum_of_squares(const std::vector<double>& v) {
  double s = 0;
  for (double u : v) s += u * u;
  return s;
}

// The state the window's fit starts from, before the start shifts.
ModalState initial_start(const ProbeModel& probe, const PreviousFit& previous, const Window& w, InitialState start) {
  switch (start) {
    case InitialState::continued: return previous.end_state;
    case InitialState::unknown: return estimate_unknown_start(probe.modal, w, probe.options);
    case InitialState::rest: break;
  }
  return ModalState::rest(probe.modal.n_modes());
}

// A continued window's prior on its start: what the previous fit knew about its end state. Flat
// when there is none, e.g. after a fit that was not trusted or across a coast.
StartPrior make_prior(const PreviousFit& previous, InitialState start, const Coordinates& coordinates,
                      const InversionOptions& options) {
  const int nb = coordinates.n_start_block();
  if (start != InitialState::continued || previous.end_cov.rows() != nb || !previous.end_cov.allFinite() ||
      !(previous.noise_var_m2 > 0) || nb == 0)
    return StartPrior(coordinates.n_packed());
  return StartPrior(start_prior_information(previous.end_cov, coordinates, options.start_prior_floor_rel),
                    previous.noise_var_m2, coordinates.n_packed());
}

// InversionOptions::parameter_drift_rel in the unknowns' order; empty: no pooling.
std::vector<double> drift_per_unknown(const ProbeModel& probe) {
  const auto& drift = probe.options.parameter_drift_rel;
  if (drift.empty()) return {};
  std::vector<double> d;
  for (const std::string& name : probe.space.unknown_names()) {
    const auto it = drift.find(name);
    TIPFORCE_DEMAND(it != drift.end());  // the Inverter checked that every unknown has one
    d.push_back(it->second);
  }
  return d;
}

// The free decay for a free start without a prior (the variable projection of the swarm), from
// the stream's cache when the window's length and period are those it was made for.
std::optional<StartProjection> make_projection(ForwardBackend& backend, const ProbeModel& probe, StreamState& stream,
                                               const Window& w, const Coordinates& coordinates, bool start_free,
                                               bool have_prior, int& solves) {
  const int n_basis = start_free && !have_prior ? coordinates.n_start_block() : 0;
  if (n_basis == 0) return std::nullopt;
  if (stream.unit_decay.rows() != w.n_samples() || stream.unit_decay.cols() != n_basis ||
      stream.unit_decay_dt_s != w.sample_period_s) {
    stream.unit_decay =
        BatchEvaluator::unit_free_decay(backend, probe.modal, stream.step, w.n_samples(), w.sample_period_s, solves);
    stream.unit_decay_dt_s = w.sample_period_s;
  }
  return StartProjection(stream.unit_decay, coordinates);
}

// The window's least-squares problem for the polish, in the packed coordinates.
class WindowLeastSquares : public LeastSquaresProblem {
 public:
  WindowLeastSquares(BatchEvaluator& evaluator, const Coordinates& coordinates, const Window& window)
      : evaluator_(evaluator), coordinates_(coordinates), window_(window), n_samples_(window.n_samples()) {}
  int n_residuals() const override { return n_samples_; }
  int n_packed() const override { return coordinates_.n_packed(); }
  int n_unknowns() const override { return coordinates_.n_unknowns(); }
  Eigen::VectorXd project(const Eigen::VectorXd& v) const override { return coordinates_.pack(coordinates_.unpack(v)); }
  double linearise(const Eigen::VectorXd& v, Linearisation& lin) override {
    return evaluator_.linearise(coordinates_.unpack(v), lin);
  }
  // Both points in one block (the same contact substeps): a difference of two discretisations
  // would enter the second derivative as 2 e / h^2.
  Eigen::VectorXd model_difference(const Eigen::VectorXd& v, const Eigen::VectorXd& probe) override {
    const Point pts[2] = {coordinates_.unpack(v), coordinates_.unpack(probe)};
    const Evaluation e = evaluator_.evaluate(std::span<const Point>(pts, 2), true, Resolution::accurate, 2);
    Eigen::VectorXd d(n_samples_);
    for (int n = 0; n < n_samples_; ++n)
      d(n) = e.signal[static_cast<std::size_t>(n_samples_ + n)] - e.signal[static_cast<std::size_t>(n)];
    return d;
  }

 private:
  BatchEvaluator& evaluator_;
  const Coordinates& coordinates_;
  const Window& window_;
  int n_samples_;
};

// The swarm's random stream for this window: from the probe's seed and the window's identity, so
// that a window is searched the same way whichever windows came before it, in whichever process
// (a per-process window counter made a cold start depend on the stream's history, and a shard of
// a line split differ from one daemon).
std::mt19937_64 window_rng(std::uint64_t seed, const Window& w) {
  const std::uint64_t id = window_identity(w);
  std::seed_seq seq{static_cast<std::uint32_t>(seed), static_cast<std::uint32_t>(seed >> 32),
                    static_cast<std::uint32_t>(id), static_cast<std::uint32_t>(id >> 32)};
  return std::mt19937_64(seq);
}

// Where a fit stopped by the deadline before it scored anything says so.
const char* const kNotBegun = "before the fit began (no fit: the start guess, sigma unknown)";

bool same_point(const Point& a, const Point& b) {
  if (a.x != b.x) return false;
  for (int i = 0; i < kStartModes; ++i)
    if (a.dq[i] != b.dq[i] || a.dv[i] != b.dv[i]) return false;
  return true;
}

Uncertainty unknown_uncertainty(int m) {
  Uncertainty u;
  u.sigma.assign(static_cast<std::size_t>(m), std::numeric_limits<double>::infinity());
  u.determined.assign(static_cast<std::size_t>(m), false);
  u.covariance = Eigen::MatrixXd::Constant(m, m, std::numeric_limits<double>::infinity());
  return u;
}

Verdict judge(double cost, double misfit, int m, const Uncertainty& u, const InversionOptions& opt,
              const std::string& cut, const std::string& outside_bounds) {
  Verdict v;
  if (!cut.empty()) {
    v.status = EstimateStatus::not_converged;
    v.prefix = cut + "; ";
    v.cut_short = true;
  } else if (!std::isfinite(cost)) {
    v.status = EstimateStatus::not_converged;
    v.prefix = "no parameter set in the bounds gave a finite misfit; ";
  } else if (m > 0 && (!u.identifiable ||
                       !std::all_of(u.sigma.begin(), u.sigma.end(), [](double s) { return std::isfinite(s); }))) {
    v.status = EstimateStatus::not_converged;
    v.singular_only = misfit <= opt.max_misfit;
  } else if (misfit > opt.max_misfit) {
    v.status = EstimateStatus::not_converged;
    v.prefix = "relative misfit " + std::to_string(misfit) + " above " + std::to_string(opt.max_misfit) +
               ": the model does not explain the window; ";
  } else if (!outside_bounds.empty()) {
    v.status = EstimateStatus::not_converged;
    v.prefix = outside_bounds;
  }
  return v;
}

}  // namespace

WindowSolver::WindowSolver(const ProbeModel& probe, ForwardBackend& backend, StreamState& stream, const Window& w,
                           SolvePlan plan)
    : probe_(probe),
      options_(probe.options),
      stream_(stream),
      window_(w),
      plan_(std::move(plan)),
      m_(probe.space.n_unknowns()),
      N_(w.n_samples()),
      energy_(sum_of_squares(w.deflection_m)),
      start_(initial_start(probe, stream.previous, w, plan_.start)),
      // Only a start at rest is known exactly; any other start is polished with the parameters.
      coordinates_(probe.space, probe.modal, std::max(std::sqrt(energy_ / N_), probe.options.min_signal_scale_m),
                   plan_.start != InitialState::rest),
      prior_(make_prior(stream.previous, plan_.start, coordinates_, probe.options)),
      parameter_prior_(prior_.present() ? parameter_prior(stream.previous, coordinates_, prior_.information(),
                                                          drift_per_unknown(probe))
                                        : std::nullopt),
      projection_(make_projection(backend, probe, stream, w, coordinates_, plan_.start != InitialState::rest,
                                  prior_.present(), decay_solves_)),
      backend_(backend),
      evaluator_(backend, probe.modal, probe.space, stream.step, w, coordinates_, start_, probe.options),
      rng_(window_rng(probe.options.seed, w)) {
  best_.point = coordinates_.centre();
}

bool WindowSolver::out_of_time(const std::string& where) {
  if (cut_.empty() && plan_.deadline.passed()) cut_ = plan_.deadline_what + " reached " + where;
  return !cut_.empty();
}

Estimate WindowSolver::solve() {
  if (plan_.polish_from && m_ > 0) {
    if (!out_of_time(kNotBegun)) {
      start_at(*plan_.polish_from);
      if (!refuted_at_the_given_values() && !out_of_time("before the polish (the given values, linearised)")) polish();
    }
  } else {
    if (can_track() && !out_of_time(kNotBegun)) tracked_ = track();
    if (!tracked_ && cut_.empty() && continuation_refuted()) {
      // Not searched further: the Inverter's start-conflict test searches the window cold.
    } else if (!tracked_ && cut_.empty() && m_ > 0 && resume()) {
      // Done: the polish from the previous window's cut-short best explained the data (resume).
    } else if (!tracked_ && cut_.empty() && m_ > 0 && physics_start()) {
      // Done: the polish from the window's own physics explained the data (physics_start).
    } else if (!tracked_ && cut_.empty() && can_track() && edge_search()) {
      // Done: an edge, found from the window's physics with the start continued (edge_search).
    } else if (!tracked_ && cut_.empty()) {
      if (m_ > 0) search();
      else if (!out_of_time(kNotBegun))
        score_by_trajectory();
      if (projection_ && std::isfinite(best_.cost) && !out_of_time("after the swarm (its best, not polished)"))
        best_.point = with_best_start_shift(evaluator_, window_, *projection_, best_.point, best_.cost);
      if (!out_of_time("before the polish (the swarm's best, not polished)")) polish();
    }
  }
  start_conflict_ = prior_.present() ? conflict_at_best() : 0.0;
  if (parameter_prior_) pool();
  const bool linearised = m_ > 0 && lin_.J.rows() == N_ && N_ > coordinates_.n_packed();
  const StartPrior& prior = pooled_prior_ ? *pooled_prior_ : prior_;
  uncertainty_ = linearised ? posterior_uncertainty(lin_.J, lin_.r, best_.cost, prior.packed_information(), widths(),
                                                    probe_.space.unknown_names(), best_.point.x, options_,
                                                    min_noise_var())
                            : unknown_uncertainty(m_);
  // The polish's last linearisation is at the answer when the polish ended there: its own solve
  // is the trajectory (one solve fewer per window).
  if (linearised && same_point(lin_.point, best_.point) && lin_.at.force_n.size() == static_cast<std::size_t>(N_))
    trajectory_ = lin_.at;
  else if (!cut_.empty() && !std::isfinite(best_.cost))
    // Never fitted (the deadline came first): a solve at the start guess would tell nothing, and
    // it was half of what each window of a backlog cost to answer (the queue after a stall of the
    // machine drains at that rate).
    trajectory_ = evaluator_.unsolved(best_.point);
  else if (!(scored_at_ && same_point(*scored_at_, best_.point)))
    trajectory_ = evaluator_.trajectory(best_.point);
  verdict_ = judge(best_.cost, misfit(best_.cost), m_, uncertainty_, options_, cut_, outside_the_bounds());
  estimate_ = report();
  return estimate_;
}

// An answer pinned at a bound whose residual keeps the structure of the motion: the data lie
// outside the bounds (e.g. a surface above h's upper bound, out of the tip's reach), and the
// answer is only the bounds' nearest point. Empty: not so (or not known: the last linearisation
// is elsewhere).
std::string WindowSolver::outside_the_bounds() const {
  if (m_ == 0 || lin_.r.size() != N_ || !same_point(lin_.point, best_.point) ||
      !(misfit(best_.cost) > options_.cold_physics_accept_misfit))
    return {};
  const double rho1 = lag1_autocorrelation(lin_.r);
  if (!(rho1 > options_.bound_max_lag1)) return {};
  const std::vector<std::string> names = probe_.space.unknown_names();
  std::string at;
  int n_at = 0;
  for (int j = 0; j < m_; ++j) {
    if (at_bound(best_.point.x[static_cast<std::size_t>(j)], options_.at_bound_tolerance))
      at += (n_at++ == 0 ? "" : " and ") + names[static_cast<std::size_t>(j)];
  }
  if (n_at == 0) return {};
  std::ostringstream o;
  o.precision(2);
  o << "the best fit within the bounds has " << at << (n_at == 1 ? " at its bound" : " at their bounds") << " and leaves a structured residual (lag-1 "
    << "autocorrelation " << rho1 << " above bound_max_lag1 " << options_.bound_max_lag1
    << "): the data likely lie outside the bounds; ";
  return o.str();
}

std::vector<double> WindowSolver::widths() const {
  std::vector<double> w(static_cast<std::size_t>(m_));
  for (int j = 0; j < m_; ++j) w[j] = coordinates_.width(j);
  return w;
}

bool WindowSolver::can_track() const {
  const PreviousFit& previous = stream_.previous;
  return m_ > 0 && previous.has_warm_start() && plan_.start != InitialState::unknown && std::isfinite(previous.misfit);
}

// Warm and continuing: the pixel is most likely close to the previous one. Polish from the
// previous estimate and keep it if the fit is as good as the previous window's; the swarm is for
// edges and jumps, where it is not.
bool WindowSolver::track() {
  start_at(stream_.previous.values);
  polish_giving_up("in the tracking polish", tracking_limit());
  if (!cut_.empty()) return false;
  // An answer at a bound is searched further as one above the limit is: the tracker can slide
  // down a curved valley to its end (honesty_test's 10 MHz rim: k at its lower bound, 0.5 N/m for
  // 12, at a misfit within the limit). Where nothing fits better, valley_start keeps it.
  if (tracking_fit(best_.cost) && every_unknown_moves_the_signal() && !at_a_bound()) return true;
  // Not only after giving up: a polish that converged (or ran out of tries) far above the limit
  // sits in another basin, which the valley's candidates reach for a fraction of the edge grid's
  // solves. tools/bench_daemon.sh's stream offline (one build): 108.4 -> 87.5 solves per window
  // (p90 226 -> 122), the same windows within 2 sigma; tipforce bench's 1 MHz line unchanged.
  return valley_start();
}

// Which unknown is h, and the tip's reach in this window (its highest position: the surface lies
// below it), where the physics candidates and the cold swarm's reach particles start. None when h
// is not an unknown or the window gives no reach.
std::optional<WindowSolver::SurfaceBelowReach> WindowSolver::surface_below_reach() const {
  const std::vector<std::string> names = probe_.space.unknown_names();
  const auto it = std::find(names.begin(), names.end(), "h_m");
  if (it == names.end()) return std::nullopt;
  const auto reach = tip_reach_m(probe_.modal, window_);
  if (!reach) return std::nullopt;
  return SurfaceBelowReach{static_cast<int>(it - names.begin()), *reach};
}

// The penetration at which the model's repulsive force reaches force_n with the unknowns at
// `values` (h moved so that the tip at z_m penetrates that far), by bisection in
// [0, max_depth_m].
double WindowSolver::depth_for_force(std::vector<double> values, int ih, double z_m, double force_n,
                                     double max_depth_m) const {
  const ForceModelKind model = probe_.space.model();
  std::vector<double> full(static_cast<std::size_t>(probe_.space.n_full()));
  auto repulsion = [&](double depth) {
    values[static_cast<std::size_t>(ih)] = z_m - depth;
    probe_.space.assemble(window_, values.data(), full.data());
    return -tip_sample_force_n(model, force_params_from(model, full), z_m, 0.0);
  };
  double lo = 0, hi = max_depth_m;
  if (!(repulsion(hi) > force_n)) return hi;
  for (int i = 0; i < 60; ++i) {
    const double mid = 0.5 * (lo + hi);
    (repulsion(mid) < force_n ? lo : hi) = mid;
  }
  return 0.5 * (lo + hi);
}

// A changed pixel (the tracking polish gave up or did not fit): candidates along the valley the
// polish crawls, each stiffness-like unknown scaled, h from this window's reach and the previous
// peak force (InversionOptions::valley_stiffness_factors), one batch at the swarm's resolution;
// then one small batch where the grid's costs point (between rungs, or beyond the grid's end);
// the best polished. True when that fits as the previous pixel did.
bool WindowSolver::valley_start() {
  const PreviousFit& previous = stream_.previous;
  const std::optional<SurfaceBelowReach> surface = surface_below_reach();
  if (!surface || !(previous.peak_force_n > 0) || options_.valley_stiffness_factors.empty() ||
      options_.valley_force_factors.empty())
    return false;
  if (out_of_time("before the valley candidates (the tracking polish's best)")) return false;
  const std::vector<double>& lo = probe_.space.lower();
  std::vector<int> stiffness_like;
  for (int j = 0; j < m_; ++j)
    if (j != surface->ih && lo[static_cast<std::size_t>(j)] > 0) stiffness_like.push_back(j);
  const std::vector<ValleyRung> grid =
      valley_grid(stiffness_like, options_.valley_stiffness_factors, options_.valley_force_factors);
  if (grid.empty()) return false;
  SearchCost cost(evaluator_, window_, projection_ ? &*projection_ : nullptr);
  std::vector<Point> candidates = valley_points(grid, *surface);
  std::vector<double> c = cost.costs(candidates);
  if (options_.valley_refinement && !out_of_time("before the valley's refinement (its grid's best)")) {
    const std::vector<Point> more = valley_refinement_points(grid, c, *surface);
    if (!more.empty()) {
      const std::vector<double> more_c = cost.costs(more);
      candidates.insert(candidates.end(), more.begin(), more.end());
      c.insert(c.end(), more_c.begin(), more_c.end());
    }
  }
  if (!cut_.empty()) return false;  // the deadline: the tracking polish's best stands
  const auto b = std::min_element(c.begin(), c.end()) - c.begin();
  if (!std::isfinite(c[static_cast<std::size_t>(b)])) return false;
  if (continuation_explains_nothing(c[static_cast<std::size_t>(b)])) {
    refuted_by_the_valley_ = true;
    return false;
  }
  const Incumbent tracked = best_;
  const Linearisation tracked_lin = lin_;
  const bool tracked_complete = last_polish_complete_;
  best_.point = candidates[static_cast<std::size_t>(b)];
  best_.cost = c[static_cast<std::size_t>(b)];
  polish("in the valley polish");
  if (!(best_.cost < tracked.cost)) {
    best_ = tracked;
    lin_ = tracked_lin;
    last_polish_complete_ = tracked_complete;
  }
  if (!cut_.empty()) return false;
  return tracking_fit(best_.cost) && every_unknown_moves_the_signal();
}

// Each rung as a point: its unknown scaled (within its bounds), h placed below this window's
// reach where the force law gives the previous peak force times the rung's force factor.
std::vector<Point> WindowSolver::valley_points(std::span<const ValleyRung> rungs, const SurfaceBelowReach& surface) const {
  const PreviousFit& previous = stream_.previous;
  const std::vector<double>& lo = probe_.space.lower();
  const std::vector<double>& hi = probe_.space.upper();
  const auto ih = static_cast<std::size_t>(surface.ih);
  std::vector<Point> points;
  points.reserve(rungs.size());
  for (const ValleyRung& rung : rungs) {
    const auto j = static_cast<std::size_t>(rung.unknown);
    std::vector<double> values = previous.values;
    values[j] = std::clamp(values[j] * rung.stiffness_factor, lo[j], hi[j]);
    const double depth = depth_for_force(values, surface.ih, surface.reach_m, rung.force_factor * previous.peak_force_n,
                                         std::max(0.0, surface.reach_m - lo[ih]));
    values[ih] = std::clamp(surface.reach_m - depth, lo[ih], hi[ih]);
    Point p;
    p.x.resize(static_cast<std::size_t>(m_));
    for (int u = 0; u < m_; ++u) p.x[u] = coordinates_.unit(u, values[static_cast<std::size_t>(u)]);
    points.push_back(std::move(p));
  }
  return points;
}

// Where the grid's costs point (valley_refinement), as points. One at a bound is off the valley:
// the stiffness clamped repeats a rung, h clamped lies where the force law cannot give the force
// (beyond the 1 -> 0.25 N/m end of bench's line, a rung at k's and h's lower bounds scored best
// at the search's resolution and the polish crawled 5 iterations from it); those are left out.
std::vector<Point> WindowSolver::valley_refinement_points(std::span<const ValleyRung> grid, std::span<const double> costs,
                                                          const SurfaceBelowReach& surface) const {
  const std::vector<ValleyRung> rungs =
      valley_refinement(grid, costs, options_.valley_stiffness_factors, options_.valley_force_factors);
  const std::vector<Point> points = valley_points(rungs, surface);
  std::vector<Point> inside;
  for (std::size_t i = 0; i < points.size(); ++i) {
    const double u = points[i].x[static_cast<std::size_t>(rungs[i].unknown)];
    const double uh = points[i].x[static_cast<std::size_t>(surface.ih)];
    if (u > 0.0 && u < 1.0 && uh > 0.0 && uh < 1.0) inside.push_back(points[i]);
  }
  return inside;
}

// After a failed tracking polish: whether its answer's start already conflicts with the prior so
// far beyond false_continuation_chi2 (continuation_refuted_chi2) that the window cannot continue
// the previous fit whatever its parameters. A restarted acquisition gave 1e7 and more; the edge
// grid and the warm swarm (some 1000 solves, 26-29 ms at 1 MHz) then only delayed the cold search
// that the start-conflict test runs anyway.
bool WindowSolver::continuation_refuted() const {
  if (refuted_by_the_valley_) return true;
  // Otherwise only at the end of a polish that ran its course: one that gave up holds parameters
  // off their optimum, and a wrong k shows as a start conflict there.
  return last_polish_complete_ && conflict_beyond_refutation();
}

bool WindowSolver::conflict_beyond_refutation() const {
  if (!prior_.present() || lin_.J.rows() != N_ || lin_.J.cols() != coordinates_.n_packed() ||
      !(options_.continuation_refuted_chi2 > 0))
    return false;
  return conflict_at_best() > refuted_chi2();
}

// After a tracking polish that gave up, before the valley's polish: whether the continued
// hypothesis explains nothing of the window, so that no polish along the valley can make it
// continue. Its start must conflict with the prior beyond refuted_chi2, and either the valley's
// best candidate leaves more than the whole signal (misfit 1: worse than no motion at all), or
// none does better than the tracked answer while that leaves more than max_misfit (the limit above
// which no answer is accepted). Measured (tools/bench_daemon.sh's streams, continuity_test): a
// changed pixel's valley candidates at least halved the tracked misfit (0.4-0.8 -> 0.2-0.36) or
// it was below 0.1; a restarted trajectory's stayed within 10 % of it (0.84-2.3), and their
// valley polish crawled 140-280 solves (5 ms at 1 MHz) to end at a misfit of 0.27-1.5. Restarts
// whose valley candidates do halve the misfit are still polished and refuted after it.
// Under a budget shorter than a cold start (bench_daemon.sh's 1.5 ms) the refuted window now
// spends its budget in the cold search rather than in the valley's polish, and runs past it by
// the physics grid's batch (false continuations' median 1.7 -> 2.4 ms there); solving the
// searches' batches in parts checked against the deadline bounded that, but left more cold
// starts cut inside their grid and more windows NOT_CONVERGED (2026-12-04, not kept).
bool WindowSolver::continuation_explains_nothing(double best_valley_cost) const {
  const bool no_better = !(best_valley_cost < best_.cost) && misfit(best_.cost) > options_.max_misfit;
  const bool worse_than_nothing = !(misfit(best_valley_cost) < 1.0);
  return (no_better || worse_than_nothing) && conflict_beyond_refutation();
}

// The start-conflict chi-square (start_prior.hpp) of best_ by lin_, its linearisation.
double WindowSolver::conflict_at_best() const {
  return start_conflict_chi2(lin_, prior_, coordinates_.pack(best_.point), m_);
}

// continuation_refuted_chi2, or the start-conflict test's own threshold where that is set higher:
// a window refuted below it would pass that test, and a fit not searched further be handed on.
double WindowSolver::refuted_chi2() const {
  return std::max(options_.continuation_refuted_chi2, options_.false_continuation_chi2);
}

// The continued hypothesis polished from another search's answer (SolvePlan::polish_from): its
// first linearisation, and whether its start conflict there is beyond continuation_refuted_chi2.
// From the parameters that explain the window alone, a window that continues the previous fit
// (an edge the continued search missed) has its inherited start close to the one fitted with
// them, and a false continuation conflicts at once (tools/bench_daemon.sh's streams: 5e7-9e10 after
// the polish, which crawled 10-20 iterations, 160-265 solves, to get there; now 8 solves, a false
// continuation of the domains stream ~670 -> ~470). Then no polish: the Inverter's misfit
// comparison decides. Where it is not refuted (a missed edge, rare) the polish's first
// linearisation repeats this one: 7 solves more than the single evaluation before.
bool WindowSolver::refuted_at_the_given_values() {
  WindowLeastSquares problem(evaluator_, coordinates_, window_);
  best_.cost = problem.linearise(coordinates_.pack(best_.point), lin_);
  last_polish_complete_ = false;
  return std::isfinite(best_.cost) && conflict_beyond_refutation();
}

// Whether each unknown's Jacobian column at the polish's answer is nonzero. One that is exactly
// zero (h above the tip's reach: no contact, so k changes nothing) is no answer: the polish
// cannot leave such a point (its gradient in k is zero), while a light contact nearby may fit as
// well (continuity_test's 5 MHz dome rim: tracked there, a window kept the previous pixel's
// values with a singular matrix; searched, it found the contact).
bool WindowSolver::every_unknown_moves_the_signal() const {
  bool all_move = lin_.J.cols() >= m_ && lin_.J.rows() == N_;
  for (int j = 0; all_move && j < m_; ++j) all_move = lin_.J.col(j).squaredNorm() > 0;
  return all_move;
}

bool WindowSolver::at_a_bound() const {
  return std::any_of(best_.point.x.begin(), best_.point.x.end(),
                     [&](double x) { return at_bound(x, options_.at_bound_tolerance); });
}

double WindowSolver::tracking_limit() const {
  const PreviousFit& previous = stream_.previous;
  // The previous residual's rms, as a misfit of this window's signal (the same when both windows'
  // signals have the same size).
  const double rms = std::sqrt(energy_ / N_);
  const double previous_misfit =
      previous.residual_rms_m > 0 && rms > 0 ? previous.residual_rms_m / rms : previous.misfit;
  return options_.tracking_misfit_ratio * previous_misfit + options_.tracking_misfit_slack;
}

bool WindowSolver::tracking_fit(double cost) const {
  const double f = misfit(cost);
  return std::isfinite(f) && f <= tracking_limit();
}

// Candidates from the window's own physics (issue 9): the surface lies below the tip's reach (the
// highest tip position over the window: the contact stops the tip there), so h is tried at the
// reach and at cold_physics_indentation_fractions below it (the indentation: large for a soft
// contact), every other unknown at the centres of a coarse grid over its bounds. Candidate c is h
// index c % per_cell in cell c / per_cell. None where h is not an unknown, the window has no
// reach, or the grid would exceed cold_physics_max_candidates.
std::optional<WindowSolver::PhysicsGrid> WindowSolver::physics_grid() const {
  if (options_.cold_physics_grid <= 0) return std::nullopt;
  const std::optional<SurfaceBelowReach> surface = surface_below_reach();
  if (!surface) return std::nullopt;
  const int ih = surface->ih;
  const double reach = surface->reach_m;
  const std::vector<double>& fr = options_.cold_physics_indentation_fractions;
  const int H = static_cast<int>(fr.size());
  // Cells per unknown other than h: the first (the stiffness-like one) cold_physics_grid, a
  // further one (a damping) cold_physics_grid_further.
  std::vector<int> cells(static_cast<std::size_t>(m_), 1);
  long n = H;
  for (int j = 0, others = 0; j < m_; ++j)
    if (j != ih)
      n *= cells[static_cast<std::size_t>(j)] = others++ == 0 ? options_.cold_physics_grid : options_.cold_physics_grid_further;
  if (H == 0 || n <= 0 || n > options_.cold_physics_max_candidates) return std::nullopt;
  // h from the reach (or the upper bound, if the reach lies above it) down towards the lower bound.
  const double h_lo = probe_.space.lower()[static_cast<std::size_t>(ih)];
  const double h_top = std::min(reach, probe_.space.upper()[static_cast<std::size_t>(ih)]);
  PhysicsGrid grid;
  grid.per_cell = H;
  const bool further = m_ > 2;
  grid.polishes = further ? options_.cold_physics_polishes_further : options_.cold_physics_polishes;
  grid.second_ratio = further ? options_.cold_physics_second_ratio_further : options_.cold_physics_second_ratio;
  grid.points.resize(static_cast<std::size_t>(n));
  for (long c = 0; c < n; ++c) {
    Point& p = grid.points[static_cast<std::size_t>(c)];
    p.x.resize(static_cast<std::size_t>(m_));
    long rest = c;
    const double f = fr[static_cast<std::size_t>(rest % H)];
    p.x[ih] = coordinates_.unit(ih, h_top - f * (h_top - h_lo));
    rest /= H;
    for (int j = 0; j < m_; ++j) {
      if (j == ih) continue;
      // Cell centres, evenly in the logarithm for a positive scale (a stiffness: what the contact
      // responds to is its ratio to the cantilever's), else evenly.
      const int G = cells[static_cast<std::size_t>(j)];
      const double u = (static_cast<double>(rest % G) + 0.5) / G;
      const double lo = probe_.space.lower()[static_cast<std::size_t>(j)];
      const double hi = probe_.space.upper()[static_cast<std::size_t>(j)];
      p.x[j] = lo > 0 && hi > lo ? coordinates_.unit(j, lo * std::pow(hi / lo, u)) : u;
      rest /= G;
    }
  }
  return grid;
}

// Scores the grid in one batch at the swarm's resolution (the start projected out when the start
// is free) and polishes from the best candidate of up to cold_physics_polishes cells (each with
// its best h; a later cell only within cold_physics_second_ratio of the best's cost: one start can
// end in a nearby local minimum that fits almost as well). `winner` keeps the lowest cost, and
// is only replaced by a lower one. False when the deadline cut it short (cut_ says where).
bool WindowSolver::polish_best_cells(const PhysicsGrid& grid, Incumbent& winner, Linearisation& winner_lin) {
  const auto t0 = std::chrono::steady_clock::now();
  const std::vector<double> c = grid_costs(grid.points);
  const double grid_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  stream_.grid_seconds = stream_.grid_seconds > 0 ? 0.75 * stream_.grid_seconds + 0.25 * grid_s : grid_s;
  const long n = static_cast<long>(grid.points.size()), H = grid.per_cell;
  std::vector<long> cells;
  for (long first = 0; first < n; first += H) {
    long b = first;
    for (long i = first; i < first + H; ++i)
      if (c[static_cast<std::size_t>(i)] < c[static_cast<std::size_t>(b)]) b = i;
    if (std::isfinite(c[static_cast<std::size_t>(b)])) cells.push_back(b);
  }
  std::sort(cells.begin(), cells.end(),
            [&](long x, long y) { return c[static_cast<std::size_t>(x)] < c[static_cast<std::size_t>(y)]; });
  cells.resize(std::min<std::size_t>(cells.size(), static_cast<std::size_t>(std::max(1, grid.polishes))));
  bool polished_here = false;
  for (long i : cells) {
    if (c[static_cast<std::size_t>(i)] > grid.second_ratio * c[static_cast<std::size_t>(cells[0])]) break;
    best_.point = grid.points[static_cast<std::size_t>(i)];
    best_.cost = c[static_cast<std::size_t>(i)];
    if (out_of_time("after the physics grid's candidates (their best, not polished)")) break;
    if (projection_) {
      best_.point = with_best_start_shift(evaluator_, window_, *projection_, best_.point, best_.cost);
      if (out_of_time("before the physics grid's polish (their best, not polished)")) break;
    }
    polish();
    polished_here = true;
    if (!cut_.empty()) break;
    if (best_.cost < winner.cost) {
      winner = best_;
      winner_lin = lin_;
    }
  }
  if (!cut_.empty()) {
    if (std::isfinite(winner.cost)) {
      best_ = winner;
      lin_ = winner_lin;
    } else if (!polished_here) {
      // Cut before any polish: best_'s cost is the grid's, over the window's head; score it over
      // the whole window by the estimate's trajectory (one solve past the deadline for both).
      score_by_trajectory();
    }
    return false;
  }
  best_ = winner;
  lin_ = winner_lin;
  return true;
}

// The grid's costs at the swarm's resolution over the window's first grid_periods periods of
// mode 1 (all of it when shorter), the start projected out when it is free.
std::vector<double> WindowSolver::grid_costs(std::span<const Point> points) {
  const double period_s = 1.0 / probe_.modal.modes()[0].frequency_hz;
  const double n_want = std::ceil(options_.grid_periods * period_s / window_.sample_period_s);
  // The whole window when it is no longer than the head, or the head under the forward solver's
  // shortest window (3 samples).
  if (!(options_.grid_periods > 0) || !(n_want < N_) || n_want < 3) {
    SearchCost cost(evaluator_, window_, projection_ ? &*projection_ : nullptr);
    return cost.costs(points);
  }
  const int n = static_cast<int>(n_want);
  Window head = window_;
  head.deflection_m.resize(static_cast<std::size_t>(n));
  if (head.drive.kind == DriveKind::sampled) head.drive.base_m.resize(static_cast<std::size_t>(n));
  BatchEvaluator head_evaluator(backend_, probe_.modal, probe_.space, stream_.step, head, coordinates_, start_,
                                options_);
  std::optional<StartProjection> head_projection;
  if (projection_) head_projection.emplace(stream_.unit_decay.topRows(n), coordinates_);
  SearchCost cost(head_evaluator, head, head_projection ? &*head_projection : nullptr);
  std::vector<double> c = cost.costs(points);
  head_solves_ += head_evaluator.forward_solves();
  return c;
}

// A cold start from the window's own physics (with the swarm, generations of 48, then the polish,
// a cold start cost ~950 forward solves on honesty_test's 5 MHz scan): the physics grid, the
// start projected out as in the swarm, the best candidates given their best start shift and
// polished. The lowest misfit stands if it explains the window (cold_answer_accepted).
// Otherwise the swarm searches the bounds exactly as it did before (its random stream untouched
// by this stage), the solves spent here counted. True: this stage's answer stands (or the
// deadline cut it). Any window whose start is free runs it, not only an UNKNOWN one: a continued
// window after an untrusted fit (no prior on its start) is a cold start from the previous end
// state, and the swarm alone found another basin there (continuity_test's 5 MHz break after an
// untrusted fit: k 6.75 +- 1.17 at misfit 6.84e-3, the window alone 2.84 +- 0.20 at 5.22e-3;
// with this stage the same answer as the window alone).
bool WindowSolver::physics_start() {
  if (!projection_) return false;
  const std::optional<PhysicsGrid> grid = physics_grid();
  if (!grid) return false;
  if (out_of_time(kNotBegun)) return true;
  const int iterations_before = iterations_;
  Incumbent winner;
  Linearisation winner_lin;
  if (!polish_best_cells(*grid, winner, winner_lin)) return true;
  if (cold_answer_accepted()) return true;
  forget_free_start(iterations_before);
  return false;
}

// A free start's answer that cold_answer_accepted refused, undone: the next stage starts afresh.
void WindowSolver::forget_free_start(int iterations_before) {
  iterations_ = iterations_before;
  best_ = Incumbent{};
  best_.point = coordinates_.centre();
  lin_ = Linearisation();
}

// best_'s cost over the whole window from the estimate's own trajectory there, kept for solve():
// one solve where a cost and then the trajectory took two.
void WindowSolver::score_by_trajectory() {
  trajectory_ = evaluator_.trajectory(best_.point);
  best_.cost = trajectory_.cost;
  scored_at_ = best_.point;
}

// best_ at these values of the unknowns, not scored (the polish's first linearisation does).
void WindowSolver::start_at(const std::vector<double>& values) {
  for (int j = 0; j < m_; ++j) best_.point.x[j] = coordinates_.unit(j, values[static_cast<std::size_t>(j)]);
  best_.cost = std::numeric_limits<double>::quiet_NaN();
}

// The polish from best_, giving up (PolishSettings::give_up_after and the rest) while its misfit
// stays above tracking_give_up_ratio x `limit` (a misfit, sqrt(cost / energy)). True: it gave up.
bool WindowSolver::polish_giving_up(const char* stage, double limit) {
  const double give_up = options_.tracking_give_up_ratio * limit;
  return polish(stage, options_.tracking_give_up_iterations, give_up * give_up * (energy_ > 0 ? energy_ : 1.0),
                options_.tracking_give_up_progress);
}

// Whether a free start's polished answer (best_, linearised in lin_) explains the window: its
// misfit within max_misfit, and its residual white (lag-1 autocorrelation at most
// cold_physics_max_lag1: what white detection noise leaves; a wrong basin leaves the contact's
// structure, smooth over many samples) or its misfit at most cold_physics_accept_misfit
// (noiseless data, whose residual is smooth even at the right answer). An unknown that the window
// does not move at all (every_unknown_moves_the_signal) is no answer either: on honesty_test's
// light contacts (indentation ~0.5 nm) the best candidate was such a point.
bool WindowSolver::cold_answer_accepted() const {
  const double f = misfit(best_.cost);  // infinite when nothing gave a finite cost: not accepted
  const double rho1 = lag1_autocorrelation(lin_.r);
  return std::isfinite(f) && f <= options_.max_misfit && every_unknown_moves_the_signal() &&
         (f <= options_.cold_physics_accept_misfit || rho1 <= options_.cold_physics_max_lag1);
}

// A fit that the deadline cut short in the previous window, resumed here with this window's
// start free: a polish from its best so far (SolvePlan::resume_from, the pixel next to this one),
// which gives up as the tracking polish does (a best so far in another basin, e.g. a false
// continuation's cut in the valley's polish, is left after one linearisation instead of being
// polished a few iterations per window along the line). Accepted as physics_start accepts its
// polish; if it is not, the state is as before and the full cold search runs. True: accepted, or
// the deadline cut it again (its best so far is resumed by the next window in turn).
bool WindowSolver::resume() {
  if (!plan_.resume_from || !projection_ || static_cast<int>(plan_.resume_from->size()) != m_) return false;
  if (out_of_time(kNotBegun)) return true;
  const int iterations_before = iterations_;
  start_at(*plan_.resume_from);
  // Before the stream's first trusted fit the tracking limit is infinite; max_misfit bounds it.
  const bool gave_up = polish_giving_up("in the polish resumed from the previous window's best",
                                        std::min(tracking_limit(), options_.max_misfit));
  if (!cut_.empty() || (!gave_up && cold_answer_accepted())) return true;
  forget_free_start(iterations_before);
  return false;
}

// An edge (the tracking polish gave up or failed): the physics grid with the start continued from
// the previous window (its prior stays), the best candidates polished, the tracking polish's end
// kept if it is better still. True when the answer fits as well as the previous pixel did (the
// tracking limit) or the deadline cut it; otherwise the warm swarm runs from the best so far.
bool WindowSolver::edge_search() {
  // Only with a prior: the start it pins down is what makes the grid's candidates comparable
  // without the swarm's start projection. After an untrusted fit (a free start) one such search
  // settled in another basin than the window's cold start (continuity_test's 5 MHz breaks: k 3.5
  // against 2.84 +- 0.2), where the warm swarm, as before, agreed with it.
  if (!options_.edge_search || plan_.start != InitialState::continued || !prior_.present()) return false;
  const std::optional<PhysicsGrid> grid = physics_grid();
  if (!grid) return false;
  if (out_of_time("before the edge search (the tracking polish's best)")) return true;
  Incumbent winner = best_;
  Linearisation winner_lin = lin_;
  const double tracking_cost = best_.cost;
  if (!polish_best_cells(*grid, winner, winner_lin)) return true;
  // The tracking polish's end is still the best: it stopped early (gave up) or converged above the
  // limit; polish it to its end.
  if (std::isfinite(tracking_cost) && best_.cost == tracking_cost) polish("in the edge search's polish");
  if (!cut_.empty()) return true;
  return tracking_fit(best_.cost) && every_unknown_moves_the_signal();
}

void WindowSolver::search() {
  const PreviousFit& previous = stream_.previous;
  // A cold start searches from the window alone: the previous estimate (another line, or before
  // a gap) is no guide, and a cold start must not depend on what came before it.
  const bool warm = previous.has_warm_start() && plan_.start != InitialState::unknown;
  SwarmSeeding seeding;
  seeding.particles = std::max(4, warm ? options_.warm_swarm_size : options_.swarm_size);
  seeding.generations = std::max(1, warm ? options_.warm_max_generations : options_.max_generations);
  if (warm) {
    // Warm: the previous estimate, then half the swarm around it, the rest over the bounds.
    for (int j = 0; j < m_; ++j) {
      seeding.centre.push_back(coordinates_.unit(j, previous.values[j]));
      const double s = std::isfinite(previous.sigma[j]) ? previous.sigma[j] / coordinates_.width(j)
                                                        : options_.warm_spread_no_sigma;
      seeding.spread.push_back(std::clamp(options_.warm_spread_sigmas * s, options_.warm_spread_min, options_.warm_spread_max));
    }
  } else {
    // Cold and tapping: some particles start with h at the tip's reach (the other unknowns
    // stratified as usual). With the start free, two drive periods also fit fairly well with the
    // tip never touching (h above its reach, where no step in k or h changes anything), and a
    // swarm that samples the bounds evenly settled there for 10 of honesty_test's 64 cold starts;
    // these particles put the tapping basin, which fits better, in front of it (6 of 64 left).
    if (const std::optional<SurfaceBelowReach> surface = surface_below_reach()) {
      seeding.reach_index = surface->ih;
      seeding.reach_unit = coordinates_.unit(surface->ih, surface->reach_m);
    }
  }
  SearchCost cost(evaluator_, window_, projection_ ? &*projection_ : nullptr);
  const SwarmOutcome swarm = run_swarm(cost, m_, seeding, options_, rng_, best_, plan_.deadline);
  iterations_ += swarm.generations;
  if (swarm.cut_short)
    out_of_time(swarm.generations == 0 ? std::string(kNotBegun)
                                       : "after " + std::to_string(swarm.generations) + " of " +
                                             std::to_string(seeding.generations) +
                                             " swarm generations (their best, not polished)");
}

bool WindowSolver::polish(const char* stage, int give_up_after, double give_up_data_cost, double give_up_progress) {
  // Not from a point known to give no finite misfit (NaN: not scored yet, the polish scores it).
  if (coordinates_.n_packed() == 0 || best_.cost == std::numeric_limits<double>::infinity()) return false;
  WindowLeastSquares problem(evaluator_, coordinates_, window_);
  PolishSettings settings;
  settings.max_iterations = plan_.start == InitialState::unknown ? options_.cold_lm_max_iterations : options_.lm_max_iterations;
  // Every linearisation has all columns, the start shifts' too: held (recomputed only at the
  // answer) they saved solves per linearisation but went stale, and the polish took more steps
  // (tipforce bench's 1 MHz line, one build: 4.0 iterations and 40.4 solves per warm window held;
  // 1.9 and 26.0 with all columns, the damping below and the predicted-gain stop of
  // levenberg_marquardt.cpp; 1.7 and 24.0 with the wider valley too).
  // Every polish of a continued window with a start prior (the tracking polish from the previous
  // pixel's answer, and the valley's and the edge grid's from their candidates) starts nearly
  // Gauss-Newton: damped at lm_initial_lambda, the k-h valley's steps were short and the damping
  // took an iteration per factor 3 to relax. The figures above and the edges' (75-91 solves)
  // are with it everywhere. Without a prior the start is free, and an undamped first step left
  // the basin (continuity_test's break after an untrusted fit).
  if (plan_.start == InitialState::continued && prior_.present())
    settings.initial_lambda = options_.lm_initial_lambda_continued;
  // Chi-square in the previous fit's noise variance, when the window continues it; a cold start
  // measures it in its own residual's.
  settings.noise_var_m2 = plan_.start == InitialState::unknown ? 0.0 : stream_.previous.noise_var_m2;
  settings.min_noise_var_m2 = min_noise_var();
  // Geodesic acceleration for a cold start's polish, which moves all columns down the valley from a
  // coarse grid point. A continued window's polish gained nothing from it: while its start columns
  // were held, more solves per window on both bench streams and on bench_daemon's stream 578 of 640
  // windows within 2 sigma against 614; with all columns (2026-12-02), in the valley and edge
  // polishes only, tipforce bench's 1 MHz line's 1 -> 4 N/m edges took 143 solves against 91.
  settings.geodesic = options_.lm_geodesic_acceleration && plan_.start == InitialState::unknown;
  settings.give_up_after = give_up_after;
  settings.give_up_data_cost = give_up_data_cost;
  settings.give_up_progress = give_up_progress;
  settings.give_up_predicted = give_up_after > 0 && options_.tracking_give_up_predicted;
  const PolishResult r =
      LevenbergMarquardt(options_).minimise(problem, prior_, coordinates_.pack(best_.point), settings, lin_,
                                            plan_.deadline);
  best_.point = coordinates_.unpack(r.v);
  best_.cost = r.data_cost;
  last_polish_complete_ = !r.gave_up && !r.cut_short;
  iterations_ += r.iterations;
  if (r.cut_short)
    out_of_time(std::string(stage) + " after " + std::to_string(r.iterations) + " iterations (its best so far)");
  return r.gave_up;
}

void WindowSolver::pool() {
  const int np = coordinates_.n_packed();
  if (!cut_.empty() || !std::isfinite(best_.cost) || lin_.J.rows() != N_ || lin_.J.cols() != np || N_ <= np ||
      !same_point(lin_.point, best_.point))
    return;
  // A window whose start conflicts with its prior is searched again by the Inverter (or refuted):
  // this answer is about to be replaced.
  if (start_conflict_ > options_.false_continuation_chi2) return;
  ParameterPrior prior = *parameter_prior_;
  double linear_chi2 = std::numeric_limits<double>::quiet_NaN();
  const std::optional<Eigen::VectorXd> kalman = kalman_point(prior, linear_chi2);
  const bool gated = linear_chi2 > options_.pool_gate_chi2;
  if (!kalman && !(gated && options_.pool_gated_iterations > 0)) return;
  // The window's own answer is complete: a deadline that has passed (or passes during the pooled
  // polish) leaves it as it is, not pooled, rather than cutting a finished fit.
  if (plan_.deadline.passed()) {
    pooling_note_ = "not pooled with the previous pixel: the deadline had passed; ";
    return;
  }
  const OwnAnswer own{best_, lin_, coordinates_.pack(best_.point)};
  const std::optional<double> chi2 = kalman ? pool_from(prior, *kalman, own) : pool_across_the_valley(prior, own);
  const double limit = kalman ? options_.pool_gate_chi2 : options_.pool_valley_chi2;
  if (chi2 && *chi2 <= limit) {
    if (gated) {
      std::ostringstream o;
      o.precision(3);
      o << "pooled with the previous pixel across this window's valley (chi-square " << linear_chi2
        << " at its own answer by its linearisation, " << *chi2 << " on the model); ";
      pooling_note_ = o.str();
    }
    return;
  }
  if (chi2) {  // otherwise the deadline came, and pooling_note_ says so
    std::ostringstream o;
    o.precision(3);
    o << "not pooled with the previous pixel: its parameters differ by chi-square ";
    if (kalman)
      o << *chi2 << " (pool_gate_chi2 " << options_.pool_gate_chi2 << "; " << linear_chi2
        << " by its own answer's linearisation); ";
    else
      o << linear_chi2 << " by its own answer's linearisation (pool_gate_chi2 " << options_.pool_gate_chi2 << "), "
        << *chi2 << " on the model (pool_valley_chi2 " << options_.pool_valley_chi2 << "); ";
    pooling_note_ = o.str();
  }
  pooled_prior_.reset();
  best_ = own.incumbent;
  lin_ = own.lin;
}

// Below the gate: the pooled polish from the Kalman point, and the innovation on the model at its
// answer (none if the deadline cut it). The short polish can stop off the valley's floor, which
// overstates the innovation (the demo cell at 5 MHz: 20.3 after one iteration where the
// linearisation gave 0.2, at a light contact whose own window left it undetermined): beyond the
// gate it is polished further before it counts.
std::optional<double> WindowSolver::pool_from(const ParameterPrior& prior, const Eigen::VectorXd& kalman,
                                              const OwnAnswer& own) {
  std::optional<PolishResult> r = pooled_polish(prior, kalman, options_.pool_max_iterations);
  if (!r) return std::nullopt;
  double chi2 = innovation_on_the_model(*r, own);
  if (!(chi2 <= options_.pool_gate_chi2) && options_.pool_gated_iterations > 0) {
    r = pooled_polish(prior, r->v, options_.pool_gated_iterations);
    if (!r) return std::nullopt;
    chi2 = innovation_on_the_model(*r, own);
  }
  return chi2;
}

// Beyond the gate (InversionOptions::pool_gated_iterations): the pooled polish from the previous
// pixel's parameters given this window's start, the other end of a valley that the linear gate
// cannot see; the innovation on the model at its answer (none if the deadline cut it). Within
// pool_valley_chi2 the prior is widened by the innovation above its expectation, as kalman_point
// widens it below the gate, and polished again.
std::optional<double> WindowSolver::pool_across_the_valley(ParameterPrior& prior, const OwnAnswer& own) {
  Eigen::VectorXd from = own.v;
  from.head(m_) = prior.centre + prior.regression * own.v.tail(prior.regression.cols());
  const std::optional<PolishResult> r = pooled_polish(prior, from, options_.pool_gated_iterations);
  if (!r) return std::nullopt;
  const double chi2 = innovation_on_the_model(*r, own);
  if (chi2 <= options_.pool_valley_chi2 && chi2 > m_) {
    prior.covariance *= chi2 / m_;
    if (!pooled_polish(prior, r->v, options_.pool_gated_iterations)) return std::nullopt;
  }
  return chi2;
}

std::optional<PolishResult> WindowSolver::pooled_polish(const ParameterPrior& prior, const Eigen::VectorXd& v0,
                                                        int iterations) {
  const StartPrior pooled = prior_.with_parameters(prior.packed_information(), prior.centre);
  WindowLeastSquares problem(evaluator_, coordinates_, window_);
  PolishSettings settings;
  settings.max_iterations = iterations;
  settings.initial_lambda = options_.lm_initial_lambda_continued;
  settings.noise_var_m2 = stream_.previous.noise_var_m2;
  settings.min_noise_var_m2 = min_noise_var();
  Linearisation lin;
  PolishResult r = LevenbergMarquardt(options_).minimise(problem, pooled, problem.project(v0), settings, lin, plan_.deadline);
  iterations_ += r.iterations;
  if (r.cut_short) {
    pooling_note_ = "not pooled with the previous pixel: the deadline came during its polish; ";
    return std::nullopt;
  }
  pooled_prior_ = pooled;
  lin_ = std::move(lin);
  best_.point = coordinates_.unpack(r.v);
  best_.cost = r.data_cost;
  return r;
}

double WindowSolver::innovation_on_the_model(const PolishResult& r, const OwnAnswer& own) const {
  return pooled_innovation_chi2(r.data_cost, r.v, *pooled_prior_, own.incumbent.cost, own.v, prior_,
                                std::max(min_noise_var(), stream_.previous.noise_var_m2));
}

std::optional<Eigen::VectorXd> WindowSolver::kalman_point(ParameterPrior& prior, double& innovation_chi2) {
  // This window's own answer and covariance (with the start prior and the bounds), as the Kalman
  // filter's measurement.
  const Uncertainty own = posterior_uncertainty(lin_.J, lin_.r, best_.cost, prior_.packed_information(), widths(),
                                                probe_.space.unknown_names(), best_.point.x, options_, min_noise_var());
  const int np = coordinates_.n_packed();
  // Without the bounds' information where the window determines its unknowns (the prior carries
  // it once already); with it where the window alone leaves a direction undetermined.
  const Eigen::MatrixXd& cov = own.data_covariance.rows() == np ? own.data_covariance : own.full_covariance;
  if (cov.rows() != np) return std::nullopt;
  if (!own.identifiable)
    pooling_note_ = "this window alone does not determine its parameters: pooled, they come from the previous pixels; ";
  const Eigen::VectorXd own_v = coordinates_.pack(best_.point);
  PoolingStep step = pooling_step(prior, own_v, cov);
  const double chi2 = innovation_chi2 = step.innovation_chi2;
  if (!(chi2 <= options_.pool_gate_chi2)) {
    std::ostringstream o;
    o.precision(3);
    o << "not pooled with the previous pixel: its parameters differ by chi-square " << chi2 << " (pool_gate_chi2 "
      << options_.pool_gate_chi2 << "); ";
    pooling_note_ = o.str();
    return std::nullopt;
  }
  // An innovation above its expectation (m) widens the prior by that ratio: a moderate change of
  // the sample, below the gate, then pulls this window's answer back towards the previous pixel's
  // less (demo cell at 5 MHz: the truth within 2 sigma in the pixel after a stiffness change of
  // more than 20 % 65 -> 83 %, over all pixels |z| < 3 98.1 -> 99.3 %).
  if (chi2 > m_) {
    prior.covariance *= chi2 / m_;
    step = pooling_step(prior, own_v, cov);
  }
  return step.v;
}

Estimate WindowSolver::report() const {
  const Uncertainty& u = uncertainty_;
  const Trajectory& t = trajectory_;
  const Verdict& v = verdict_;
  Estimate est;
  est.names = probe_.space.unknown_names();
  est.misfit = misfit(best_.cost);
  est.values = coordinates_.values(best_.point.x);
  est.sigma = u.sigma;
  est.determined = u.determined;
  est.covariance = u.covariance;
  const ForceModelKind model = probe_.space.model();
  // Without a trajectory (a window never fitted) nothing is derived: NaN, not a guess's values.
  constexpr double kNone = std::numeric_limits<double>::quiet_NaN();
  const DerivedQuantities d =
      t.force_n.empty()
          ? DerivedQuantities{kNone, kNone, kNone, kNone}
          : derived_quantities(model, force_params_from(model, t.full), t.force_n, t.tip_z_m,
                               FullParams(ParameterLayout(model), t.full).drive(DriveParameter::frequency_hz),
                               window_.sample_period_s);
  est.peak_force_n = d.peak_force_n;
  est.mean_force_n = d.mean_force_n;
  est.max_indentation_m = d.max_indentation_m;
  est.dissipated_energy_j = d.dissipated_energy_j;
  est.iterations = iterations_;
  // The free-decay basis (decay_solves_) is the probe's, computed once per window length and
  // period and kept: not counted, or the same window would cost 4 solves more when it happens
  // to be the first of its length.
  est.forward_solves = evaluator_.forward_solves() + head_solves_;
  est.status = v.status;
  const std::string note = v.prefix + u.notes + pooling_note_;
  if (!note.empty()) est.message = note.substr(0, note.size() - 2);
  return est;
}

void WindowSolver::hand_off() {
  const Estimate& est = estimate_;
  const Uncertainty& u = uncertainty_;
  const Trajectory& t = trajectory_;
  const Verdict& verdict = verdict_;
  PreviousFit& p = stream_.previous;
  const int np = coordinates_.n_packed();
  // A cut-short fit's best so far, for the next window to resume (resume_cut_fits); where the
  // deadline came before anything was scored, the older best so far stays if this window
  // continued its line (a chain of cut windows keeps its point), and none otherwise.
  if (!verdict.cut_short)
    p.resume_values.clear();
  else if (m_ > 0 && std::isfinite(best_.cost))
    p.resume_values = est.values;
  else if (window_.initial != InitialState::continued)
    p.resume_values.clear();
  p.coasted_samples = 0;
  p.end_state = t.end_state;
  p.end_t_s = window_.t0_s + N_ * window_.sample_period_s;
  p.full = t.full;
  p.have_end_state = true;
  // How uncertain that end state is (start modes, physical units): the next window inherits it,
  // through the end-state sensitivities of the polish's last linearisation (at this point).
  p.forget_prior();
  const auto usable = [np](const Eigen::MatrixXd& c) { return c.rows() == np && c.allFinite(); };
  // Pooling: the next window adds the bounds' information itself, so it inherits the covariance
  // without it (else each window would count the bounds once more), its start's and its
  // parameters' alike, so that their joint prior is one Gaussian.
  const bool pooled = !options_.parameter_drift_rel.empty() && usable(u.data_covariance);
  const Eigen::MatrixXd& c = pooled ? u.data_covariance : u.full_covariance;
  if (np > 0 && lin_.J_end.cols() == np && lin_.J_end.allFinite() && usable(c)) {
    p.end_cov = lin_.J_end * c * lin_.J_end.transpose();
    if (pooled) {
      p.param_cov = c.topLeftCorner(m_, m_);
      p.param_end_cov = c.topRows(m_) * lin_.J_end.transpose();
    }
  }
  // A fit that leaves an unknown undetermined hands on no prior either: its end state's linearised
  // covariance spans a range of that unknown (the bounds) over which the trajectory is anything
  // but linear, so it can claim to know a start that the next window's data contradict.
  if (!std::all_of(est.determined.begin(), est.determined.end(), [](bool d) { return d; })) p.forget_prior();
  if (est.status == EstimateStatus::ok) {
    p.values = est.values;
    p.sigma = est.sigma;
    p.misfit = est.misfit;
    p.residual_rms_m = std::isfinite(best_.cost) ? std::sqrt(best_.cost / N_) : 0.0;
    p.peak_force_n = est.peak_force_n;
    p.noise_var_m2 = u.noise_var_m2;
    return;
  }
  // Do not seed the next pixel from a fit we do not trust, nor give its end state a prior. A fit
  // that explains the window but leaves an unknown undetermined (a contact so light that the
  // estimate just misses the surface) keeps the last trusted warm start: without it, the next
  // window's cold swarm on two drive periods can settle in a wrong basin that fits as well.
  p.forget_prior();
  if (!verdict.singular_only || verdict.cut_short) {
    p.values.clear();
    p.sigma.clear();
    // Nor continue from its end state (SPEC 5: a NOT_CONVERGED fit never seeds the next window):
    // the next window starts unknown.
    p.have_end_state = false;
  }
}

}  // namespace tipforce::inversion
