#include "inversion/batch_evaluator.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "tipforce/parameter_layout.hpp"

namespace tipforce::inversion {

BatchEvaluator::BatchEvaluator(ForwardBackend& backend, const ModalModel& modal, const ParameterSpace& space,
                               const StepCoefficients& step, const Window& window, const Coordinates& coordinates,
                               const ModalState& start, const InversionOptions& options)
    : backend_(backend),
      space_(space),
      window_(window),
      coordinates_(coordinates),
      start_(start),
      relative_step_(options.jacobian_relative_step),
      problem_{&modal, &step, space.model(), &window, default_substeps(space.model())} {
  // With the drive among the unknowns a batch's drive varies, which takes one step per sample; the
  // single trajectory (a shared drive) would otherwise take two at 10 MHz, a discretisation the
  // fit did not use.
  if (space.drive_is_unknown()) problem_.samples_per_step = 1;
  // The swarm only has to find the basin: it resolves contact more coarsely than the polish.
  search_problem_ = problem_;
  search_problem_.contact_rad_per_substep = options.search_contact_rad_per_substep;
  search_problem_.crossing_rad_per_substep = options.search_crossing_rad_per_substep;
}

Evaluation BatchEvaluator::evaluate(std::span<const Point> pts, bool want_signal, Resolution resolution,
                                    int sets_per_block) {
  return evaluate_sets(pts, want_signal, false, resolution, sets_per_block);
}

Evaluation BatchEvaluator::evaluate_sets(std::span<const Point> pts, bool want_signal, bool want_end,
                                         Resolution resolution, int sets_per_block, bool want_force) {
  const int S = static_cast<int>(pts.size()), nf = space_.n_full();
  std::vector<double> soa(static_cast<std::size_t>(nf) * S), full(static_cast<std::size_t>(nf));
  std::vector<ModalState> starts;
  bool shifted = false;
  for (const Point& p : pts) shifted |= p.shifted();
  for (int s = 0; s < S; ++s) {
    const std::vector<double> u = coordinates_.values(pts[s].x);
    space_.assemble(window_, u.data(), full.data());
    for (int k = 0; k < nf; ++k) soa[static_cast<std::size_t>(k) * S + s] = full[k];
    if (shifted) starts.push_back(coordinates_.shifted(start_, pts[s]));
  }
  ForwardBatch batch;
  batch.n_sets = S;
  batch.params = soa;
  // One shared start unless some point moves it (the backend then needs no per-set states).
  batch.initial = shifted ? std::span<const ModalState>(starts) : std::span<const ModalState>(&start_, 1);
  batch.drive_varies = space_.drive_is_unknown();
  batch.want_signal = want_signal;
  batch.want_end_state = want_end;
  batch.sets_per_block = sets_per_block;
  batch.want_force = want_force;
  backend_.solve(resolution == Resolution::search ? search_problem_ : problem_, batch, out_);
  forward_solves_ += S;
  Evaluation e;
  e.cost = out_.cost;
  for (double& c : e.cost)
    if (!std::isfinite(c)) c = std::numeric_limits<double>::infinity();
  if (want_signal) e.signal = std::move(out_.signal);
  return e;
}

double BatchEvaluator::linearise(const Point& p, Linearisation& lin) {
  const int m = coordinates_.n_unknowns(), np = coordinates_.n_packed(), nb = coordinates_.n_start_block();
  const int N = window_.n_samples();
  // The columns in groups, each behind its own copy of p and solved in one block (the difference
  // of two sets is then taken at the same contact substeps: ForwardBatch::sets_per_block), as few
  // groups as the widest block allows. A Jacobian that fits one block is solved on the calling
  // thread: two blocks of four on this machine's two cores took as long as one block of eight on
  // one (1 MHz, 1250 samples: 122-143 against 119-125 us; the cores slow each other, and a
  // worker that slept between linearisations wakes late), for an extra copy of p and both cores.
  // tipforce bench's 1 MHz line, interleaved: warm p50 520-628 -> 360-371 us, p99 1465-1716 ->
  // 1136-1158 us, 22.2 -> 19.6 solves per warm window.
  const int groups = std::max(1, (np + kMaxColumnsPerGroup - 1) / kMaxColumnsPerGroup);
  const int per_group = (np + groups - 1) / groups;
  std::vector<int> set_of_column(static_cast<std::size_t>(np)), base_of_column(static_cast<std::size_t>(np));
  std::vector<Point> pts;
  const Eigen::VectorXd c = coordinates_.pack(p);
  std::vector<double> steps(static_cast<std::size_t>(np));
  for (int j = 0; j < np; ++j) {
    if (j % per_group == 0) pts.push_back(p);
    base_of_column[j] = static_cast<int>(pts.size()) - 1 - j % per_group;
    Eigen::VectorXd d = c;
    double h = relative_step_ * std::max(1.0, std::abs(c(j)));
    if (j < m && c(j) + h > 1.0) h = -h;  // stay inside the bounds
    d(j) += h;
    steps[j] = h;
    set_of_column[j] = static_cast<int>(pts.size());
    pts.push_back(coordinates_.unpack(d));
  }
  if (pts.empty()) pts.push_back(p);
  const Evaluation e = evaluate_sets(pts, true, true, Resolution::accurate, 1 + per_group, true);
  lin.point = p;
  lin.at.full.resize(static_cast<std::size_t>(space_.n_full()));
  const std::vector<double> values = coordinates_.values(p.x);
  space_.assemble(window_, values.data(), lin.at.full.data());
  lin.at.force_n.assign(out_.force_n.begin(), out_.force_n.begin() + N);
  lin.at.tip_z_m.assign(out_.tip_z_m.begin(), out_.tip_z_m.begin() + N);
  lin.at.end_state = out_.end_state[0];
  lin.r.resize(N);
  lin.J.resize(N, np);
  lin.J_end.resize(nb, np);
  for (int n = 0; n < N; ++n) lin.r(n) = window_.deflection_m[n] - e.signal[n];
  for (int j = 0; j < np; ++j) {
    const std::size_t sj = static_cast<std::size_t>(set_of_column[j]), s0 = static_cast<std::size_t>(base_of_column[j]);
    for (int n = 0; n < N; ++n) lin.J(n, j) = (e.signal[sj * N + n] - e.signal[s0 * N + n]) / steps[j];
    for (int i = 0; i < coordinates_.n_start_modes(); ++i) {
      lin.J_end(2 * i, j) = (out_.end_state[sj].q[i] - out_.end_state[s0].q[i]) / steps[j];
      lin.J_end(2 * i + 1, j) = (out_.end_state[sj].v[i] - out_.end_state[s0].v[i]) / steps[j];
    }
  }
  return e.cost[0];
}

Trajectory BatchEvaluator::unsolved(const Point& p) const {
  Trajectory t;
  t.full.resize(static_cast<std::size_t>(space_.n_full()));
  const std::vector<double> values = coordinates_.values(p.x);
  space_.assemble(window_, values.data(), t.full.data());
  return t;
}

Trajectory BatchEvaluator::trajectory(const Point& p) {
  Trajectory t = unsolved(p);
  const ModalState start = coordinates_.shifted(start_, p);
  ForwardBatch batch;
  batch.n_sets = 1;
  batch.params = t.full;
  batch.initial = std::span<const ModalState>(&start, 1);
  batch.want_force = batch.want_end_state = true;
  backend_.solve(problem_, batch, out_);
  forward_solves_ += 1;
  t.force_n = out_.force_n;
  t.tip_z_m = out_.tip_z_m;
  t.end_state = out_.end_state[0];
  t.cost = std::isfinite(out_.cost[0]) ? out_.cost[0] : std::numeric_limits<double>::infinity();
  return t;
}

Eigen::MatrixXd BatchEvaluator::unit_free_decay(ForwardBackend& backend, const ModalModel& modal,
                                                const StepCoefficients& step, int N, double sample_period_s,
                                                int& forward_solves) {
  const int n_modes = std::min(kStartModes, modal.n_modes()), n_basis = 2 * n_modes;
  std::vector<ModalState> starts(static_cast<std::size_t>(n_basis), ModalState::rest(modal.n_modes()));
  // Shifts well inside double range: the response is linear in them, so any size gives the same
  // unit response.
  const double unit_q = 1e-9, unit_v = 1e-9 * modal.modes()[0].omega_rad_per_s;
  for (int i = 0; i < n_modes; ++i) {
    starts[2 * i].q[i] = unit_q;
    starts[2 * i + 1].v[i] = unit_v;
  }
  // Model none with zero drive amplitude: the cantilever's free decay from each shifted start.
  const ParameterLayout none_layout(ForceModelKind::none);
  std::vector<double> quiet_params(static_cast<std::size_t>(none_layout.n_full()) * n_basis, 0.0);
  for (int s = 0; s < n_basis; ++s)  // frequency: any
    quiet_params[static_cast<std::size_t>(none_layout.drive_index(DriveParameter::frequency_hz)) * n_basis + s] = 1.0;
  ForwardBatch batch;
  batch.n_sets = n_basis;
  batch.params = quiet_params;
  batch.initial = starts;
  batch.want_signal = true;
  Window quiet;
  quiet.sample_period_s = sample_period_s;
  quiet.t0_s = 0;
  quiet.deflection_m.assign(static_cast<std::size_t>(N), 0.0);
  ForwardOutput out;
  backend.solve(ForwardProblem{&modal, &step, ForceModelKind::none, &quiet, default_substeps(ForceModelKind::none)},
                batch, out);
  forward_solves += n_basis;
  Eigen::MatrixXd unit(N, n_basis);
  for (int j = 0; j < n_basis; ++j)
    for (int n = 0; n < N; ++n) unit(n, j) = out.signal[static_cast<std::size_t>(j) * N + n] / (j % 2 == 0 ? unit_q : unit_v);
  return unit;
}

ModalState BatchEvaluator::coast(ForwardBackend& backend, const ModalModel& modal, const ParameterSpace& space,
                                 const StepCoefficients& step, std::span<const double> full, const ModalState& from,
                                 double t0_s, double sample_period_s, long n_samples) {
  const FullParams last(ParameterLayout(space.model()), full);
  Window coast;
  coast.sample_period_s = sample_period_s;
  coast.t0_s = t0_s;
  coast.drive.kind = DriveKind::sine;
  coast.drive.amplitude_m = last.drive(DriveParameter::amplitude_m);
  coast.drive.frequency_hz = last.drive(DriveParameter::frequency_hz);
  coast.drive.phase_rad = last.drive(DriveParameter::phase_rad);
  coast.drive.chirp_hz_per_s = last.drive(DriveParameter::chirp_hz_per_s);
  if (coast.drive.chirp_hz_per_s != 0) coast.drive.kind = DriveKind::chirp;
  coast.deflection_m.assign(static_cast<std::size_t>(n_samples), 0.0);
  ForwardBatch batch;
  batch.n_sets = 1;
  batch.params = full;
  batch.initial = std::span<const ModalState>(&from, 1);
  batch.want_end_state = true;
  ForwardOutput out;
  backend.solve(ForwardProblem{&modal, &step, space.model(), &coast, default_substeps(space.model())}, batch, out);
  return out.end_state[0];
}

}  // namespace tipforce::inversion
