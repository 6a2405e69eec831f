// The probe's stream of windows: validation, the window's start, one WindowSolver per window
// (lib/src/inversion/window_solver.cpp: tracking polish or swarm, Levenberg-Marquardt, covariance,
// derived quantities), and what a fit hands the next window. README "How it works" has the
// reasoning.
#include "tipforce/inversion.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <sstream>
#include <string>

#include "inversion/batch_evaluator.hpp"
#include "inversion/deadline.hpp"
#include "inversion/stream_state.hpp"
#include "inversion/window_solver.hpp"
#include "tipforce/assert.hpp"
#include "tipforce/detail/forward_setup.hpp"

namespace tipforce {

Inverter::Inverter(ProbeModel probe, ForwardBackend& backend)
    : probe_(std::move(probe)),
      backend_(&backend),
      limits_(probe_.limits.value_or(window_limits(probe_.modal, 0.0, probe_.space, kMaxWindowSamples))),
      state_(std::make_unique<inversion::StreamState>()) {
  const auto missing = probe_.space.missing();
  TIPFORCE_THROW_UNLESS(missing.empty(), "probe '" + probe_.name + "': parameter '" + (missing.empty() ? "" : missing[0]) +
                                             "' is neither fixed nor unknown");
  const std::optional<std::string> bad = probe_.options.problem();
  TIPFORCE_THROW_UNLESS(!bad, "probe '" + probe_.name + "': inversion option " + bad.value_or(""));
  const auto& drift = probe_.options.parameter_drift_rel;
  if (!drift.empty()) {
    const std::vector<std::string> names = probe_.space.unknown_names();
    for (const std::string& name : names)
      TIPFORCE_THROW_UNLESS(drift.contains(name), "probe '" + probe_.name + "': inversion option parameter_drift_rel names no drift for unknown '" + name + "' (pooling needs one for every unknown)");
    for (const auto& [name, value] : drift)
      TIPFORCE_THROW_UNLESS(std::find(names.begin(), names.end(), name) != names.end(),
                            "probe '" + probe_.name + "': inversion option parameter_drift_rel names '" + name + "', which is not an unknown");
  }
}

Inverter::~Inverter() = default;
Inverter::Inverter(Inverter&&) noexcept = default;
Inverter& Inverter::operator=(Inverter&&) noexcept = default;

bool Inverter::has_warm_start() const { return state_->previous.has_warm_start(); }
const ModalState* Inverter::last_end_state() const {
  return state_->previous.have_end_state ? &state_->previous.end_state : nullptr;
}
double Inverter::last_end_t_s() const { return state_->previous.end_t_s; }
const std::vector<double>& Inverter::last_full_params() const { return state_->previous.full; }

void Inverter::reset() { state_->previous = inversion::PreviousFit{}; }

std::optional<long> Inverter::coast_samples(double t0_s, double sample_period_s, int max_gap_samples) const {
  const inversion::PreviousFit& p = state_->previous;
  if (max_gap_samples < 0) max_gap_samples = probe_.options.max_coast_samples;
  if (!p.have_end_state || p.full.empty() || sample_period_s != state_->step_dt_s) return std::nullopt;
  const double gap = (t0_s - p.end_t_s) / sample_period_s;
  const long n_gap = std::lround(gap);
  // The limit counts every sample coasted since the fit was made, not just this gap's.
  if (!std::isfinite(gap) || n_gap < 0 || std::abs(gap - n_gap) > probe_.options.coast_grid_tolerance ||
      n_gap + p.coasted_samples > max_gap_samples)
    return std::nullopt;
  return n_gap;
}

bool Inverter::coast_to(double t0_s, double sample_period_s, int max_gap_samples) {
  const std::optional<long> n_gap = coast_samples(t0_s, sample_period_s, max_gap_samples);
  if (!n_gap) return false;
  if (*n_gap == 0) return true;
  inversion::PreviousFit& p = state_->previous;
  p.end_state = inversion::BatchEvaluator::coast(*backend_, probe_.modal, probe_.space, state_->step, p.full,
                                                 p.end_state, p.end_t_s, sample_period_s, *n_gap);
  p.end_t_s = t0_s;
  p.coasted_samples += *n_gap;
  // The covariance belonged to the state before the gap; rather than carry it across (which would
  // need the gap's transition too), the window after the gap estimates its start from its own
  // data (a flat prior), which is honest if a little less precise.
  p.forget_prior();
  return true;
}

void Inverter::use_sample_period(double sample_period_s) {
  if (state_->step_dt_s == sample_period_s) return;
  state_->step = make_step_coefficients(probe_.modal, sample_period_s / default_substeps(probe_.space.model()));
  state_->step_dt_s = sample_period_s;
}

std::optional<std::string> Inverter::sample_period_problem(double sample_period_s) const {
  if (state_->step_dt_s == sample_period_s) return std::nullopt;  // stepped at it before
  if (const auto why = step_problem(probe_.modal, sample_period_s / default_substeps(probe_.space.model())))
    return "probe '" + probe_.name + "' cannot be solved at this window's sample period: " + *why;
  return std::nullopt;
}

void Inverter::prepare(double sample_period_s) {
  TIPFORCE_THROW_UNLESS(std::isfinite(sample_period_s) && sample_period_s > 0,
                        "probe '" + probe_.name + "': cannot prepare for sample period " + std::to_string(sample_period_s) +
                            " s: it must be finite and positive");
  use_sample_period(sample_period_s);
  // Two samples of the cantilever at rest, undriven, with every unknown at the middle of its
  // bounds: the backend builds its step tables for this step whatever the window holds (the
  // backend keeps them per step length, the contact's own refinements included).
  Window w;
  w.sample_period_s = sample_period_s;
  w.drive.kind = DriveKind::sine;
  w.drive.frequency_hz = probe_.modal.modes()[0].frequency_hz;
  w.deflection_m.assign(2, 0.0);
  const ParameterSpace& space = probe_.space;
  std::vector<double> middle(static_cast<std::size_t>(space.n_unknowns())), full(static_cast<std::size_t>(space.n_full()));
  for (std::size_t k = 0; k < middle.size(); ++k) middle[k] = 0.5 * (space.lower()[k] + space.upper()[k]);
  space.assemble(w, middle.data(), full.data());
  const ModalState rest = ModalState::rest(probe_.modal.n_modes());
  ForwardBatch batch;
  batch.n_sets = 1;
  batch.params = full;
  batch.initial = std::span<const ModalState>(&rest, 1);
  ForwardOutput out;
  ForwardProblem problem{&probe_.modal, &state_->step, space.model(), &w, default_substeps(space.model())};
  backend_->solve(problem, batch, out);
  // Where that took two samples per step, the tables of one step per sample too: a drive among
  // the unknowns and an odd-length window use those.
  if (detail::samples_per_step(problem, batch) == 1) return;
  problem.samples_per_step = 1;
  backend_->solve(problem, batch, out);
}

namespace {
std::string ms(double v) {
  std::ostringstream o;
  o.precision(3);
  o << v;
  return o.str();
}
}  // namespace

inversion::Deadline Inverter::deadline(const WindowContext& context, std::chrono::steady_clock::time_point t_start) const {
  const double budget_ms = probe_.options.deadline_ms;
  if (!(budget_ms > 0)) return inversion::Deadline();
  return inversion::Deadline(context.budget_start.value_or(t_start) +
                             std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                                 std::chrono::duration<double, std::milli>(budget_ms)));
}

std::string Inverter::deadline_what(const WindowContext& context, std::chrono::steady_clock::time_point t_start) const {
  std::string what = "deadline of " + ms(probe_.options.deadline_ms) + " ms (deadline_ms)";
  if (!context.budget_start) return what;
  const double waited_ms = std::chrono::duration<double, std::milli>(t_start - *context.budget_start).count();
  return what + " from receipt (the fit began " + ms(waited_ms) + " ms after it)";
}

// The data pull the start far from where the previous fit says the cantilever is: either the
// continued search missed the parameters (an edge the warm swarm did not cross), or the window
// does not continue the fit at all. A search from the window alone tells them apart: the continued
// fit polished from its answer conflicts again only in the second case, and there the window
// alone explains the data better than the continued fit can (by more than the misfit's own
// scatter between neighbours, tracking_misfit_ratio). When the search from the window alone finds
// nothing better, the continued fit stands.
Estimate Inverter::answer_start_conflict(const Window& w, const inversion::SolvePlan& plan,
                                         inversion::WindowSolver& first, const Estimate& first_estimate) {
  const InversionOptions& opt = probe_.options;
  const double first_conflict = first.start_conflict();
  std::ostringstream note;
  note.precision(3);
  note << "start-conflict chi-square " << first_conflict;
  // The search from the window alone begins with the physics grid, one batch that the deadline
  // cannot cut. Begun after the continued search, it ran 2-3 ms past a 1.5 ms budget
  // (tools/bench_daemon.sh: false continuations at 3.5-4.2 ms, the slowest windows that no stall
  // of the machine explains), and the windows behind waited. Where the grids so far say it would
  // end past the deadline, or the deadline came before it began, the next window starts cold
  // instead, with its whole budget.
  if (state_->grid_seconds > 0 && plan.deadline.passes_within(state_->grid_seconds))
    return unanswered_false_continuation(
        first_estimate, first_estimate.forward_solves, note.str(),
        "its physics grid (" + ms(1e3 * state_->grid_seconds) + " ms in this probe's grids so far) would end past the deadline");
  inversion::SolvePlan cold_plan = plan;
  cold_plan.start = InitialState::unknown;
  inversion::WindowSolver cold(probe_, *backend_, *state_, w, cold_plan);
  Estimate c = cold.solve();
  int solves = first_estimate.forward_solves + c.forward_solves;
  if (cold.skipped())
    return unanswered_false_continuation(first_estimate, solves, note.str(), "the deadline came before it began");
  if (c.status == EstimateStatus::ok && !cold.cut_short()) {
    inversion::SolvePlan again_plan = plan;
    again_plan.polish_from = c.values;
    inversion::WindowSolver again(probe_, *backend_, *state_, w, again_plan);
    Estimate a = again.solve();
    solves += a.forward_solves;
    note << ", then " << again.start_conflict() << " at a cold search's answer";
    if (a.status == EstimateStatus::ok && !(again.start_conflict() > opt.false_continuation_chi2)) {
      again.hand_off();
      a.forward_solves = solves;
      a.message = "continued fit found by a search from the window alone (the continued search had missed it: " +
                  note.str() + ")" + (a.message.empty() ? "" : "; " + a.message);
      return a;
    }
  }
  if (!(first_estimate.misfit > opt.tracking_misfit_ratio * c.misfit + opt.tracking_misfit_slack)) {
    first.hand_off();
    Estimate e = first_estimate;
    e.forward_solves = solves;
    note << " above " << opt.false_continuation_chi2
         << ", but the window alone explains the data no better: the continued fit stands";
    e.message = note.str() + (e.message.empty() ? "" : "; " + e.message);
    return e;
  }
  cold.hand_off();
  note << ", above " << opt.false_continuation_chi2 << "; relative misfit " << first_estimate.misfit
       << " continued, " << c.misfit << " from the window alone";
  c.message = "marked CONTINUED, but the data do not continue the previous fit (" + note.str() +
              "): inverted as a cold start" + (c.message.empty() ? "" : "; " + c.message);
  c.forward_solves = solves;
  return c;
}

// A window whose start conflicts with the previous fit beyond false_continuation_chi2, left
// without the search from the window alone (why): NOT_CONVERGED with the continued fit's values,
// and nothing of that fit seeds the next window, which starts cold.
Estimate Inverter::unanswered_false_continuation(const Estimate& first_estimate, int solves, const std::string& conflict,
                                                 const std::string& why) {
  reset();
  Estimate e = first_estimate;
  e.status = EstimateStatus::not_converged;
  e.forward_solves = solves;
  std::ostringstream o;
  o.precision(3);
  o << "marked CONTINUED, but the data do not continue the previous fit (" << conflict << ", above "
    << probe_.options.false_continuation_chi2 << "); not searched from the window alone: " << why << " (deadline_ms "
    << ms(probe_.options.deadline_ms) << "); the next window starts cold";
  if (!first_estimate.message.empty()) o << "; " << first_estimate.message;
  e.message = o.str();
  return e;
}

Estimate Inverter::invert(const Window& w, const WindowContext& context) {
  // The one timing of a window's solve (WindowProcessor reports it, it does not time again).
  const auto t_start = std::chrono::steady_clock::now();
  Estimate est = invert_valid(w, context, t_start);
  est.solve_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count();
  return est;
}

Estimate Inverter::invert_valid(const Window& w, const WindowContext& context,
                                std::chrono::steady_clock::time_point t_start) {
  // The one validation of a window (WindowProcessor and decode_window leave it to this).
  std::optional<std::string> problem = window_problem(w);
  if (!problem) problem = window_problem_for_probe(w, limits_);
  if (!problem) problem = sample_period_problem(w.sample_period_s);
  if (problem) {
    Estimate est;
    est.names = probe_.space.unknown_names();
    est.status = EstimateStatus::rejected;
    est.message = *problem;
    est.misfit = std::nan("");
    return est;
  }
  const StreamStep step = stream_step(last_seq_, context.seq);
  if (context.seq) last_seq_ = context.seq;
  const bool coastable = step == StreamStep::gap && coast_samples(w.t0_s, w.sample_period_s, -1).has_value();
  const StartChoice choice = decide_start(w.initial, step, state_->previous.have_end_state, coastable);
  if (choice == StartChoice::coast_then_continue) coast_to(w.t0_s, w.sample_period_s);
  use_sample_period(w.sample_period_s);
  const InitialState start = choice == StartChoice::rest ? InitialState::rest
                             : choice == StartChoice::cold ? InitialState::unknown
                                                           : InitialState::continued;
  inversion::SolvePlan plan{start, std::nullopt, std::nullopt, deadline(context, t_start),
                            deadline_what(context, t_start)};
  // With resume_cut_fits, a cold start of the window right after a cut fit on the same line
  // resumes that fit (not a line start, not across a gap or a broken sequence).
  if (probe_.options.resume_cut_fits && start == InitialState::unknown && w.initial == InitialState::continued &&
      step == StreamStep::follows && !state_->previous.resume_values.empty())
    plan.resume_from = state_->previous.resume_values;
  inversion::WindowSolver first(probe_, *backend_, *state_, w, plan);
  Estimate est = first.solve();
  // A window the deadline left unfitted (it waited out its budget in the queue behind a slow one)
  // is a gap in the stream, not a bad fit: where it would have continued the previous fit, that
  // fit is coasted across it (within max_coast_samples since it was made) and the next window
  // continues it. Handed on as a failed fit, it made the next window start cold (a full cold
  // search, itself cut, and so on). A skipped line start or start at rest is handed on as any cut
  // fit: the next window does not continue the line before it.
  if (first.skipped() && start == InitialState::continued &&
      coast_to(w.t0_s + w.n_samples() * w.sample_period_s, w.sample_period_s)) {
    est.message += "; the next window continues the previous fit across this one";
    return est;
  }
  if (first.cut_short() || !(first.start_conflict() > probe_.options.false_continuation_chi2)) {
    first.hand_off();
    return est;
  }
  return answer_start_conflict(w, plan, first, est);
}

}  // namespace tipforce
