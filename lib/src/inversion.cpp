// One window's inversion: tracking polish from the previous pixel (warm, continued windows), else
// PSO with a warm start -> Levenberg-Marquardt polish -> Gauss-Newton covariance (HAC-inflated)
// -> derived quantities. Unknowns are searched in coordinates normalised to their bounds. Unless
// the window starts at rest, modes 1 and 2's displacement and velocity at the first sample are four
// nuisance unknowns polished with the parameters: flat for an unknown start (and projected out
// during the swarm), and for a continued window a Gaussian prior centred on the previous fit's end
// state with that fit's covariance, which this window's data update (a Kalman step). README "How
// it works" has the reasoning.
#include "tipforce/inversion.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <numbers>
#include <optional>
#include <random>

#include "tipforce/assert.hpp"
#include "tipforce/drive.hpp"
#include "tipforce/reference.hpp"

namespace tipforce {
namespace {

constexpr int kNuisanceModes = 2;  // modes whose initial state an unknown start estimates

struct Point {
  std::vector<double> x;  // unknowns, normalised to [0, 1]
  // Nuisance: shifts of the initial displacement and velocity of modes 1 and 2 (scaled units).
  double dq[kNuisanceModes] = {0, 0}, dv[kNuisanceModes] = {0, 0};
  bool shifted() const { return dq[0] != 0 || dv[0] != 0 || dq[1] != 0 || dv[1] != 0; }
};

struct Evaluation {
  std::vector<double> cost;
  std::vector<double> signal;  // [set * N + n] when requested
};

double clamp01(double v) { return std::clamp(v, 0.0, 1.0); }

// The tip's furthest excursion toward the sample in the window (m): base motion plus measured
// deflection, for a displacement sensor. The surface stops the tip near there, so it is where h
// lies when the tip taps: a cold start's guess at h. Nothing for an optical lever (its reading is
// a slope, not the tip's displacement).
std::optional<double> tip_reach_m(const ModalModel& modal, const Window& w) {
  if (modal.sensor() != Sensor::displacement || w.deflection_m.empty()) return std::nullopt;
  double reach = -std::numeric_limits<double>::infinity();
  for (int n = 0; n < w.n_samples(); ++n) {
    const double y = w.drive.kind == DriveKind::sampled
                         ? w.drive.base_m[static_cast<std::size_t>(n)]
                         : base_motion(w.drive.kind, w.drive.amplitude_m, w.drive.frequency_hz, w.drive.phase_rad,
                                       w.drive.chirp_hz_per_s, w.t0_s + n * w.sample_period_s)
                               .y_m;
    reach = std::max(reach, y + w.deflection_m[static_cast<std::size_t>(n)]);
  }
  return reach;
}

// The inverse of a symmetric positive semi-definite matrix, or nothing where it is (numerically)
// singular: an eigenvalue below min_rel_eigenvalue times the largest. Judged and inverted at unit
// diagonal (the correlation form), so that an unknown the signal barely moves (small diagonal:
// poor precision) is not mistaken for a degenerate one (columns that repeat one another).
std::optional<Eigen::MatrixXd> inverse_spd(const Eigen::MatrixXd& a, double min_rel_eigenvalue) {
  const Eigen::VectorXd d = a.diagonal();
  if (!a.allFinite() || !(d.array() > 0).all()) return std::nullopt;
  const Eigen::VectorXd scale = d.cwiseSqrt().cwiseInverse();
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(scale.asDiagonal() * a * scale.asDiagonal());
  const Eigen::VectorXd ev = eig.eigenvalues();
  if (!(ev.minCoeff() > min_rel_eigenvalue * ev.maxCoeff())) return std::nullopt;
  return Eigen::MatrixXd(scale.asDiagonal() * (eig.eigenvectors() * ev.cwiseInverse().asDiagonal() * eig.eigenvectors().transpose()) *
                         scale.asDiagonal());
}

// The information matrix (inverse covariance) of a continued window's start shifts, in the
// window's scaled nuisance coordinates (q / q_scale, v / v_scale per mode), from the previous
// fit's end-state covariance in physical units (q in m, v in m/s; modes 1-2 interleaved). Its
// variances get a floor of floor_rel^2 in those coordinates: the forward solver's own error carried
// across the window edge, which no fit can remove, and a guard against an exactly singular
// covariance (a direction that the previous fit's parameters do not move) becoming infinite
// information.
Eigen::MatrixXd start_prior_information(const Eigen::MatrixXd& end_cov_phys, const double* q_scale, const double* v_scale,
                                        int n_modes, double floor_rel) {
  const int nb = 2 * n_modes;
  Eigen::VectorXd scale(nb);
  for (int i = 0; i < n_modes; ++i) {
    scale(2 * i) = q_scale[i];
    scale(2 * i + 1) = v_scale[i];
  }
  const Eigen::MatrixXd cov = scale.cwiseInverse().asDiagonal() * end_cov_phys * scale.cwiseInverse().asDiagonal();
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(0.5 * (cov + cov.transpose()));
  const double floor_var = std::max(floor_rel * floor_rel, 1e-300);
  const Eigen::VectorXd var = eig.eigenvalues().cwiseMax(0.0).array() + floor_var;
  return eig.eigenvectors() * var.cwiseInverse().asDiagonal() * eig.eigenvectors().transpose();
}

}  // namespace

Inverter::Inverter(ProbeModel probe, ForwardBackend& backend) : probe_(std::move(probe)), backend_(&backend) {
  const auto missing = probe_.space.missing();
  TIPFORCE_THROW_UNLESS(missing.empty(), "probe '" + probe_.name + "': parameter '" + (missing.empty() ? "" : missing[0]) +
                                             "' is neither fixed nor unknown");
}

void Inverter::reset() {
  previous_end_cov_.resize(0, 0);
  previous_noise_var_m2_ = 0;
  previous_misfit_ = std::numeric_limits<double>::infinity();
  previous_values_.clear();
  previous_sigma_.clear();
  have_end_state_ = false;
}

bool Inverter::coast_to(double t0_s, double sample_period_s, int max_gap_samples) {
  if (!have_end_state_ || previous_full_.empty() || sample_period_s != cached_dt_s_) return false;
  const double gap = (t0_s - previous_end_t_s_) / sample_period_s;
  const long n_gap = std::lround(gap);
  if (!std::isfinite(gap) || n_gap < 0 || std::abs(gap - n_gap) > 1e-3 || n_gap > max_gap_samples) return false;
  if (n_gap == 0) return true;
  const ParameterSpace& space = probe_.space;
  const FullParams last(ParameterLayout(space.model()), previous_full_);
  Window coast;
  coast.sample_period_s = sample_period_s;
  coast.t0_s = previous_end_t_s_;
  coast.drive.kind = DriveKind::sine;
  coast.drive.amplitude_m = last.drive(DriveParameter::amplitude_m);
  coast.drive.frequency_hz = last.drive(DriveParameter::frequency_hz);
  coast.drive.phase_rad = last.drive(DriveParameter::phase_rad);
  coast.drive.chirp_hz_per_s = last.drive(DriveParameter::chirp_hz_per_s);
  if (coast.drive.chirp_hz_per_s != 0) coast.drive.kind = DriveKind::chirp;
  coast.deflection_m.assign(static_cast<std::size_t>(n_gap), 0.0);
  ForwardBatch batch;
  batch.n_sets = 1;
  batch.params = previous_full_;
  batch.initial = std::span<const ModalState>(&previous_end_state_, 1);
  batch.want_end_state = true;
  ForwardOutput out;
  backend_->solve(ForwardProblem{&probe_.modal, &step_, space.model(), &coast, default_substeps(space.model())}, batch,
                  out);
  previous_end_state_ = out.end_state[0];
  previous_end_t_s_ = t0_s;
  // The covariance belonged to the state before the gap; rather than carry it across (which would
  // need the gap's transition too), the window after the gap estimates its start from its own
  // data (a flat prior), which is honest if a little less precise.
  previous_end_cov_.resize(0, 0);
  return true;
}

Estimate Inverter::invert(const Window& w) {
  const auto t_start = std::chrono::steady_clock::now();
  Estimate est;
  est.names = probe_.space.unknown_names();
  auto finish = [&](Estimate& e) -> Estimate {
    e.solve_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_start).count();
    ++windows_seen_;
    return e;
  };
  if (auto problem = window_problem(w)) {
    est.status = EstimateStatus::rejected;
    est.message = *problem;
    est.misfit = std::nan("");
    return finish(est);
  }
  const ModalModel& modal = probe_.modal;
  const ParameterSpace& space = probe_.space;
  const InversionOptions& opt = probe_.options;
  const int M = modal.n_modes(), N = w.n_samples(), m = space.n_unknowns(), nf = space.n_full();
  const int substeps = default_substeps(space.model());
  if (cached_dt_s_ != w.sample_period_s) {
    step_ = make_step_coefficients(modal, w.sample_period_s / substeps);
    cached_dt_s_ = w.sample_period_s;
  }

  // ---- initial state ------------------------------------------------------------------------
  InitialState initial = w.initial;
  if (initial == InitialState::continued && !have_end_state_) initial = InitialState::unknown;
  ModalState init = ModalState::rest(M);
  if (initial == InitialState::continued) init = previous_end_state_;
  const bool unknown_start = initial == InitialState::unknown;
  // Only a start at rest is known exactly; any other start is polished with the parameters.
  const bool start_free = initial != InitialState::rest;
  double signal_rms = 0;
  for (double u : w.deflection_m) signal_rms += u * u;
  signal_rms = std::sqrt(signal_rms / N);
  const int n_nuis_modes = std::min(kNuisanceModes, M);
  double nq_scale[kNuisanceModes] = {0, 0}, nv_scale[kNuisanceModes] = {0, 0};
  for (int i = 0; i < n_nuis_modes; ++i) {
    nq_scale[i] = std::max(signal_rms, 1e-12) / std::abs(modal.modes()[i].phi_tip);
    nv_scale[i] = nq_scale[i] * modal.modes()[i].omega_rad_per_s;
  }
  if (unknown_start) {
    // The drive's linear steady state for every mode, then mode 1 moved to match the first samples
    // (a quadratic fitted over an eighth of the first mode's period).
    if (w.drive.kind != DriveKind::sampled)
      init = linear_steady_state(modal, w.drive.amplitude_m, w.drive.frequency_hz, w.drive.phase_rad, w.t0_s);
    const double period = 1.0 / modal.modes()[0].frequency_hz;
    const int k = std::clamp(static_cast<int>(period / (8 * w.sample_period_s)), 3, N);
    if (k >= 3) {
      Eigen::MatrixXd A(k, 3);
      Eigen::VectorXd b(k);
      for (int i = 0; i < k; ++i) {
        const double t = i * w.sample_period_s;
        A.row(i) << 1.0, t, t * t;
        b(i) = w.deflection_m[i];
      }
      const Eigen::Vector3d c = A.colPivHouseholderQr().solve(b);
      double s0 = 0, s1 = 0;
      for (int i = 1; i < M; ++i) {
        s0 += modal.sensor_gain(i) * init.q[i];
        s1 += modal.sensor_gain(i) * init.v[i];
      }
      init.q[0] = (c(0) - s0) / modal.sensor_gain(0);
      init.v[0] = (c(1) - s1) / modal.sensor_gain(0);
    }
  }

  // ---- evaluation of a batch of points --------------------------------------------------------
  const std::vector<double>& lo = space.lower();
  const std::vector<double>& hi = space.upper();
  auto to_params = [&](const std::vector<double>& x) {
    std::vector<double> u(static_cast<std::size_t>(m));
    for (int j = 0; j < m; ++j) u[j] = lo[j] + x[j] * (hi[j] - lo[j]);
    return u;
  };
  const ForwardProblem problem{&modal, &step_, space.model(), &w, substeps};
  // The swarm only has to find the basin: it resolves contact more coarsely than the polish.
  ForwardProblem search_problem = problem;
  search_problem.contact_rad_per_substep = probe_.options.search_contact_rad_per_substep;
  ForwardOutput fwd;
  auto evaluate = [&](const std::vector<Point>& pts, bool want_signal, bool want_end = false, bool search = false) {
    const int S = static_cast<int>(pts.size());
    std::vector<double> soa(static_cast<std::size_t>(nf) * S), full(static_cast<std::size_t>(nf));
    std::vector<ModalState> inits;
    bool shifted = false;
    for (const Point& p : pts) shifted |= p.shifted();
    for (int s = 0; s < S; ++s) {
      const std::vector<double> u = to_params(pts[s].x);
      space.assemble(w, u.data(), full.data());
      for (int k = 0; k < nf; ++k) soa[static_cast<std::size_t>(k) * S + s] = full[k];
      if (shifted) {
        inits.push_back(init);
        for (int i = 0; i < n_nuis_modes; ++i) {
          inits.back().q[i] += pts[s].dq[i] * nq_scale[i];
          inits.back().v[i] += pts[s].dv[i] * nv_scale[i];
        }
      }
    }
    ForwardBatch batch;
    batch.n_sets = S;
    batch.params = soa;
    batch.initial = shifted ? std::span<const ModalState>(inits) : std::span<const ModalState>(&init, 1);
    batch.drive_varies = space.drive_is_unknown();
    batch.want_signal = want_signal;
    batch.want_end_state = want_end;
    backend_->solve(search ? search_problem : problem, batch, fwd);
    est.forward_solves += S;
    Evaluation e;
    e.cost = fwd.cost;
    for (double& c : e.cost)
      if (!std::isfinite(c)) c = std::numeric_limits<double>::infinity();
    if (want_signal) e.signal = std::move(fwd.signal);
    return e;
  };

  // A continued window's prior on its start: what the previous fit knew about its end state.
  // Empty (flat) when there is none, e.g. after a fit that was not trusted or across a coast.
  const int nb = 2 * n_nuis_modes;
  Eigen::MatrixXd prior_info;  // nb x nb information matrix, in the scaled nuisance coordinates
  if (initial == InitialState::continued && previous_end_cov_.rows() == nb && previous_end_cov_.allFinite() &&
      previous_noise_var_m2_ > 0) {
    prior_info = start_prior_information(previous_end_cov_, nq_scale, nv_scale, n_nuis_modes, opt.start_prior_floor_rel);
  }
  const bool have_prior = prior_info.rows() == nb && nb > 0;
  // Variable projection for a start without a prior: the signal is (nearly) linear in the initial
  // state of modes 1 and 2, so the swarm scores each candidate by the residual left after the best
  // such shift, i.e. with the free-decay responses projected out. Otherwise a start that is a
  // little off sends the swarm to a wrong basin that the polish cannot leave.
  const int n_nuis = start_free && !have_prior ? nb : 0;
  const int n_basis = n_nuis;
  Eigen::MatrixXd decay;    // N x n_basis: response to a unit (scaled) shift of modes 1-2's start
  Eigen::MatrixXd decay_q;  // orthonormal basis of its columns
  if (n_basis > 0) {
    // The free decay depends on the window's length and sample period only: computed once for
    // unit (physical) shifts and kept, then scaled to this window's signal.
    if (decay_unit_.rows() != N || decay_unit_.cols() != n_basis || decay_dt_s_ != w.sample_period_s) {
      std::vector<ModalState> starts(static_cast<std::size_t>(n_basis), ModalState::rest(M));
      const double unit_q = 1e-9, unit_v = 1e-9 * modal.modes()[0].omega_rad_per_s;  // well inside double range
      for (int i = 0; i < n_nuis_modes; ++i) {
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
      quiet.sample_period_s = w.sample_period_s;
      quiet.t0_s = 0;
      quiet.deflection_m.assign(static_cast<std::size_t>(N), 0.0);
      backend_->solve(ForwardProblem{&modal, &step_, ForceModelKind::none, &quiet, substeps}, batch, fwd);
      est.forward_solves += n_basis;
      decay_unit_.resize(N, n_basis);
      for (int j = 0; j < n_basis; ++j)
        for (int n = 0; n < N; ++n)
          decay_unit_(n, j) = fwd.signal[static_cast<std::size_t>(j) * N + n] / (j % 2 == 0 ? unit_q : unit_v);
      decay_dt_s_ = w.sample_period_s;
    }
    decay = decay_unit_;
    for (int i = 0; i < n_nuis_modes; ++i) {
      decay.col(2 * i) *= nq_scale[i];
      decay.col(2 * i + 1) *= nv_scale[i];
    }
    decay_q = decay.householderQr().householderQ() * Eigen::MatrixXd::Identity(N, n_basis);
  }
  auto swarm_evaluate = [&](const std::vector<Point>& pts) {
    if (n_nuis == 0) return evaluate(pts, false, false, true);
    Evaluation e = evaluate(pts, true, false, true);
    for (std::size_t s = 0; s < pts.size(); ++s) {
      if (!std::isfinite(e.cost[s])) continue;
      Eigen::VectorXd res(N);
      for (int n = 0; n < N; ++n) res(n) = w.deflection_m[n] - e.signal[s * N + n];
      e.cost[s] = std::max(0.0, e.cost[s] - (decay_q.transpose() * res).squaredNorm());
    }
    return e;
  };

  Point best;
  best.x.assign(static_cast<std::size_t>(m), 0.5);
  double best_cost = std::numeric_limits<double>::infinity();
  std::mt19937_64 rng(opt.seed + 0x9E3779B97F4A7C15ull * windows_seen_);

  // ---- local polish: Levenberg-Marquardt on unknowns (+ nuisance) -----------------------------
  const int nn = start_free ? nb : 0;
  const int np = m + nn;
  // The prior's penalty, in the cost's units (m^2): the prior's information weighed by the
  // previous fit's residual variance, so that cost / variance is the negative log posterior.
  auto prior_cost = [&](const Eigen::VectorXd& packed) {
    if (!have_prior) return 0.0;
    const Eigen::VectorXd s = packed.tail(nb);
    return previous_noise_var_m2_ * s.dot(prior_info * s);
  };
  // The prior's information on the packed unknowns, in the same units (zero where it is flat).
  Eigen::MatrixXd prior_hessian = Eigen::MatrixXd::Zero(np, np);
  if (have_prior) prior_hessian.bottomRightCorner(nb, nb) = previous_noise_var_m2_ * prior_info;
  Eigen::MatrixXd J;
  Eigen::VectorXd r;
  // d(end state of modes 1-2)/d(packed unknowns) at the same point as J, from the same batch: how
  // the state the next window inherits depends on this window's unknowns.
  Eigen::MatrixXd J_end;
  auto pack = [&](const Point& p) {
    Eigen::VectorXd v(np);
    for (int j = 0; j < m; ++j) v(j) = p.x[j];
    for (int i = 0; i < nn / 2; ++i) {
      v(m + 2 * i) = p.dq[i];
      v(m + 2 * i + 1) = p.dv[i];
    }
    return v;
  };
  auto unpack = [&](const Eigen::VectorXd& v) {
    Point p;
    p.x.resize(static_cast<std::size_t>(m));
    for (int j = 0; j < m; ++j) p.x[j] = clamp01(v(j));
    for (int i = 0; i < nn / 2; ++i) {
      p.dq[i] = v(m + 2 * i);
      p.dv[i] = v(m + 2 * i + 1);
    }
    return p;
  };
  // Residuals and forward-difference Jacobian of the simulated signal at p (one batch), with the
  // end-state sensitivities from the same sets. With all_columns false only the parameters'
  // columns are recomputed (m + 1 sets) and the start shifts' columns are kept from the last full
  // linearisation.
  auto linearise = [&](const Point& p, bool all_columns) {
    const int n_cols = all_columns || J.cols() != np ? np : m;
    std::vector<Point> pts{p};
    const Eigen::VectorXd c = pack(p);
    std::vector<double> steps(static_cast<std::size_t>(n_cols));
    for (int j = 0; j < n_cols; ++j) {
      Eigen::VectorXd d = c;
      double h = 1e-6 * std::max(1.0, std::abs(c(j)));
      if (j < m && c(j) + h > 1.0) h = -h;  // stay inside the bounds
      d(j) += h;
      steps[j] = h;
      pts.push_back(unpack(d));
    }
    Evaluation e = evaluate(pts, true, true);
    r.resize(N);
    J.conservativeResize(N, np);
    J_end.conservativeResize(nb, np);
    for (int n = 0; n < N; ++n) {
      const double u0 = e.signal[n];
      r(n) = w.deflection_m[n] - u0;
      for (int j = 0; j < n_cols; ++j) J(n, j) = (e.signal[static_cast<std::size_t>(j + 1) * N + n] - u0) / steps[j];
    }
    for (int j = 0; j < n_cols; ++j)
      for (int i = 0; i < n_nuis_modes; ++i) {
        J_end(2 * i, j) = (fwd.end_state[j + 1].q[i] - fwd.end_state[0].q[i]) / steps[j];
        J_end(2 * i + 1, j) = (fwd.end_state[j + 1].v[i] - fwd.end_state[0].v[i]) / steps[j];
      }
    return e.cost[0];
  };
  // The noise's variance per sample: the cost's natural unit (chi-square = cost / it).
  auto noise_variance = [&](double data_cost) {
    return previous_noise_var_m2_ > 0 ? previous_noise_var_m2_ : data_cost / std::max(1, N - np);
  };
  // A start with a prior moves little, and so do its columns of the Jacobian, which cost more
  // than the parameters' (a batch of m + 1 sets is about half the price of one of np + 1). The
  // polish then iterates with them held, and checks its answer against a full linearisation.
  const bool hold_start_columns = have_prior && m > 0;
  auto polish = [&]() {
    if (np == 0 || !std::isfinite(best_cost)) return;
    // Each trial point is evaluated together with its Jacobian (one batch): an accepted step
    // needs no second call. The step minimises the misfit plus the start prior's penalty;
    // best_cost stays the misfit alone.
    double data_cost = linearise(best, true);
    double cost = data_cost + prior_cost(pack(best));
    double lambda = opt.lm_initial_lambda;
    int it = 0;
    Eigen::MatrixXd J_keep, J_end_keep;
    Eigen::VectorXd r_keep;
    const int max_iterations = unknown_start ? opt.cold_lm_max_iterations : opt.lm_max_iterations;
    // Levenberg-Marquardt until converged; false if a step could not be found.
    auto iterate = [&](bool all_columns) {
      bool converged = false;
      for (; it < max_iterations && !converged; ++it) {
        const Eigen::MatrixXd A = J.transpose() * J + prior_hessian;
        const Eigen::VectorXd g = J.transpose() * r - prior_hessian * pack(best);
        J_keep = J;
        J_end_keep = J_end;
        r_keep = r;
        bool improved = false;
        for (int tries = 0; tries < opt.lm_max_tries && !improved; ++tries) {
          Eigen::MatrixXd Ad = A;
          for (int j = 0; j < np; ++j) Ad(j, j) += lambda * std::max(A(j, j), 1e-30);
          const Eigen::VectorXd delta = Ad.ldlt().solve(g);
          if (!delta.allFinite()) {
            lambda *= opt.lm_lambda_up_singular;
            continue;
          }
          const Point cand = unpack(pack(best) + delta);
          const double c_data = linearise(cand, all_columns);
          const double c = c_data + prior_cost(pack(cand));
          if (c < cost) {
            const double rel = (cost - c) / cost;
            const double step = m > 0 ? delta.head(m).cwiseAbs().maxCoeff() : 0.0;
            const double chi2_drop = (cost - c) / noise_variance(c_data);
            best = cand;
            cost = c;
            data_cost = c_data;
            lambda = std::max(lambda / opt.lm_lambda_down, opt.lm_min_lambda);
            improved = true;
            // Converged: the cost no longer moves (relatively, or in chi-square: then the estimate
            // moves by a small fraction of its sigma), or the step is a millionth of the bounds.
            converged = rel < opt.lm_rel_cost_tolerance || chi2_drop < opt.lm_chi2_tolerance || step < opt.lm_step_tolerance;
          } else {
            J = J_keep;
            J_end = J_end_keep;
            r = r_keep;
            lambda *= opt.lm_lambda_up;
          }
        }
        if (!improved) return false;
      }
      return true;
    };
    const bool found = iterate(!hold_start_columns);
    if (hold_start_columns && it > 0) {
      // The full Jacobian at the answer: the covariance and the inherited end state need it, and
      // it says whether the held columns stopped the polish short. Iterate on with full columns
      // only if an exact Gauss-Newton step would still gain more than the tolerance.
      data_cost = linearise(best, true);
      cost = data_cost + prior_cost(pack(best));
      const Eigen::MatrixXd A = J.transpose() * J + prior_hessian;
      const Eigen::VectorXd g = J.transpose() * r - prior_hessian * pack(best);
      const Eigen::VectorXd delta = A.ldlt().solve(g);
      const double predicted_chi2_gain = delta.allFinite() ? g.dot(delta) / noise_variance(data_cost) : INFINITY;
      if (!found || !(predicted_chi2_gain < opt.lm_chi2_tolerance)) iterate(true);
    }
    best_cost = data_cost;
    est.iterations += it;
  };

  // ---- global search: particle swarm -----------------------------------------------------------
  // Warm and continuing: the pixel is most likely close to the previous one. Polish from the
  // previous estimate and keep it if the fit is as good as the previous window's; the swarm is
  // for edges and jumps, where it is not.
  bool tracked = false;
  if (m > 0 && has_warm_start() && !unknown_start && std::isfinite(previous_misfit_)) {
    for (int j = 0; j < m; ++j) best.x[j] = clamp01((previous_values_[j] - lo[j]) / (hi[j] - lo[j]));
    best_cost = evaluate({best}, false).cost[0];
    polish();
    double energy0 = 0;
    for (double u : w.deflection_m) energy0 += u * u;
    const double misfit = energy0 > 0 ? std::sqrt(best_cost / energy0) : std::sqrt(best_cost);
    tracked = std::isfinite(misfit) && misfit <= opt.tracking_misfit_ratio * previous_misfit_ + opt.tracking_misfit_slack;
  }
  if (m > 0 && !tracked) {
    const bool warm = has_warm_start();
    const int P = std::max(4, warm ? opt.warm_swarm_size : opt.swarm_size);
    const int G = std::max(1, warm ? opt.warm_max_generations : opt.max_generations);
    std::uniform_real_distribution<double> uni(0.0, 1.0);
    std::normal_distribution<double> gauss(0.0, 1.0);
    std::vector<Point> pos(static_cast<std::size_t>(P)), pbest;
    std::vector<std::vector<double>> vel(static_cast<std::size_t>(P), std::vector<double>(static_cast<std::size_t>(m)));
    std::vector<double> prev_x(static_cast<std::size_t>(m)), prev_s(static_cast<std::size_t>(m));
    if (warm) {
      for (int j = 0; j < m; ++j) {
        prev_x[j] = clamp01((previous_values_[j] - lo[j]) / (hi[j] - lo[j]));
        const double s = std::isfinite(previous_sigma_[j]) ? previous_sigma_[j] / (hi[j] - lo[j]) : 0.1;
        prev_s[j] = std::clamp(3.0 * s, 0.02, 0.25);
      }
    }
    // Cold and tapping: an eighth of the swarm starts with h at the tip's reach (the other unknowns
    // stratified as usual). With the start free, two drive periods also fit fairly well with the
    // tip never touching (h above its reach, where no step in k or h changes anything), and a
    // swarm that samples the bounds evenly settled there for 10 of honesty_test's 64 cold starts;
    // these particles put the tapping basin, which fits better, in front of it (6 of 64 left).
    int h_index = -1;
    double h_reach_m = 0;
    if (!warm) {
      const auto it = std::find(est.names.begin(), est.names.end(), "h_m");
      const auto reach = tip_reach_m(modal, w);
      if (it != est.names.end() && reach) {
        h_index = static_cast<int>(it - est.names.begin());
        h_reach_m = *reach;
      }
    }
    for (int p = 0; p < P; ++p) {
      pos[p].x.resize(static_cast<std::size_t>(m));
      // Warm: the previous estimate, then half the swarm around it, the rest over the bounds.
      // Cold: stratified over the bounds along each axis.
      for (int j = 0; j < m; ++j) {
        if (warm && p == 0) pos[p].x[j] = prev_x[j];
        else if (warm && p < P / 2) pos[p].x[j] = clamp01(prev_x[j] + prev_s[j] * gauss(rng));
        else if (j == h_index && p % 8 == 0) pos[p].x[j] = clamp01((h_reach_m - lo[j]) / (hi[j] - lo[j]));
        else pos[p].x[j] = (((p * (2 * j + 1) * 7919) % P) + uni(rng)) / P;
        vel[p][j] = 0.1 * (uni(rng) - 0.5);
      }
    }
    Evaluation e = swarm_evaluate(pos);
    pbest = pos;
    std::vector<double> pcost = e.cost;
    for (int p = 0; p < P; ++p)
      if (pcost[p] < best_cost) {
        best_cost = pcost[p];
        best = pos[p];
      }
    int stall = 0, gen = 0;
    constexpr double kInertia = 0.7298, kC = 1.49618;  // Clerc's constriction
    for (gen = 1; gen < G && stall < opt.stall_generations; ++gen) {
      for (int p = 0; p < P; ++p)
        for (int j = 0; j < m; ++j) {
          double& v = vel[p][j];
          v = kInertia * v + kC * uni(rng) * (pbest[p].x[j] - pos[p].x[j]) + kC * uni(rng) * (best.x[j] - pos[p].x[j]);
          v = std::clamp(v, -0.3, 0.3);
          double x = pos[p].x[j] + v;
          if (x < 0 || x > 1) {
            x = clamp01(x);
            v = -0.5 * v;
          }
          pos[p].x[j] = x;
        }
      e = swarm_evaluate(pos);
      const double before = best_cost;
      for (int p = 0; p < P; ++p) {
        if (e.cost[p] < pcost[p]) {
          pcost[p] = e.cost[p];
          pbest[p] = pos[p];
        }
        if (e.cost[p] < best_cost) {
          best_cost = e.cost[p];
          best = pos[p];
        }
      }
      stall = (before - best_cost > opt.stall_rel_tolerance * before) ? 0 : stall + 1;
    }
    est.iterations = gen;
  } else if (m == 0) {
    best_cost = evaluate({best}, false).cost[0];
  }

  if (!tracked && n_nuis > 0 && std::isfinite(best_cost)) {
    // Seed the polish with the best start shift for the swarm's answer.
    Evaluation e = evaluate({best}, true);
    Eigen::VectorXd res(N);
    for (int n = 0; n < N; ++n) res(n) = w.deflection_m[n] - e.signal[n];
    const Eigen::VectorXd c = decay.colPivHouseholderQr().solve(res);
    Point shifted = best;
    for (int i = 0; i < n_nuis_modes; ++i) {
      shifted.dq[i] = c(2 * i);
      shifted.dv[i] = c(2 * i + 1);
    }
    const double shifted_cost = evaluate({shifted}, false).cost[0];
    if (shifted_cost < e.cost[0]) best = shifted;
    best_cost = std::min(shifted_cost, e.cost[0]);
  }
  if (!tracked) polish();

  // ---- uncertainty ---------------------------------------------------------------------------
  double energy = 0;
  for (double u : w.deflection_m) energy += u * u;
  est.misfit = energy > 0 ? std::sqrt(best_cost / energy) : std::sqrt(best_cost);
  const std::vector<double> values = to_params(best.x);
  est.values = values;
  est.sigma.assign(static_cast<std::size_t>(m), std::numeric_limits<double>::infinity());
  est.determined.assign(static_cast<std::size_t>(m), false);
  est.covariance = Eigen::MatrixXd::Constant(m, m, std::numeric_limits<double>::infinity());
  std::string note;
  Eigen::MatrixXd full_cov_x;  // covariance of all polished unknowns, normalised coordinates
  bool identifiable = true;    // the data (and start prior) alone leave no direction undetermined
  double noise_var_m2 = 0;     // the residual variance the covariance was scaled with
  if (m > 0 && J.rows() == N && N > np) {
    // Residual variance, inflated by the residuals' autocorrelation (a HAC correction): white
    // noise leaves it as it is, while structure the model cannot follow (a start inherited from
    // the previous pixel's fit, a model that is slightly wrong) shrinks the number of independent
    // samples and must widen the uncertainty rather than bias it silently.
    double s2 = best_cost / (N - np);
    {
      const double r0 = r.squaredNorm();
      const int lags = std::min(N / 4, 200);
      double tau = 1.0;
      for (int k = 1; k <= lags && r0 > 0; ++k) {
        const double rho = r.head(N - k).dot(r.tail(N - k)) / r0;
        tau += 2.0 * (1.0 - static_cast<double>(k) / (lags + 1)) * rho;  // Bartlett weights
      }
      s2 *= std::max(1.0, tau);
    }
    // Posterior information: this window's data plus the start prior (a Kalman update). The
    // prior can only add information, so a continued window is never less certain than the same
    // window with its start unknown: what is inherited is bounded by construction.
    Eigen::MatrixXd info = J.transpose() * J / s2;
    if (have_prior) info.bottomRightCorner(nb, nb) += prior_info;
    identifiable = inverse_spd(info, opt.singular_rel_eigenvalue).has_value();
    if (!identifiable) note += "parameters not identifiable from this window (singular Gauss-Newton matrix); ";
    // The bounds are prior knowledge too: a uniform distribution over them has variance 1/12 in
    // the normalised coordinates. Added as Gaussian information, it keeps an unknown the window
    // does not determine (k of a contact so light or so stiff that it hardly moves the signal)
    // from a linearised sigma thousands of times its bounds, and adds next to nothing where the
    // data do determine it.
    for (int j = 0; j < m; ++j) info(j, j) += 12.0;
    if (const auto cov_x = inverse_spd(info, opt.singular_rel_eigenvalue)) {
      // Normalised unknowns (+ nuisance); the nuisance is marginalised by taking the block.
      noise_var_m2 = s2;
      full_cov_x = *cov_x;
      Eigen::MatrixXd cov = cov_x->topLeftCorner(m, m);
      for (int i = 0; i < m; ++i)
        for (int j = 0; j < m; ++j) cov(i, j) *= (hi[i] - lo[i]) * (hi[j] - lo[j]);
      est.covariance = cov;
      for (int j = 0; j < m; ++j) est.sigma[j] = std::sqrt(std::max(cov(j, j), 0.0));
      for (int j = 0; j < m; ++j) {
        est.determined[j] = identifiable && std::sqrt((*cov_x)(j, j)) <= opt.undetermined_sigma_fraction / std::sqrt(12.0);
        if (identifiable && !est.determined[j])
          note += est.names[j] + " barely determined by this window (sigma near the spread of its bounds); ";
      }
      for (int i = 0; i < m; ++i)
        for (int j = i + 1; j < m; ++j) {
          const double corr = cov(i, j) / std::sqrt(cov(i, i) * cov(j, j));
          if (std::abs(corr) > opt.trade_off_correlation)
            note += est.names[i] + " and " + est.names[j] + " trade off (correlation " + std::to_string(corr) + "); ";
        }
    }
    for (int j = 0; j < m; ++j)
      if (best.x[j] <= 1e-9 || best.x[j] >= 1 - 1e-9) note += est.names[j] + " at its bound; ";
  }

  // ---- derived quantities and the end state at the estimate --------------------------------
  {
    std::vector<double> full(static_cast<std::size_t>(nf));
    space.assemble(w, values.data(), full.data());
    ModalState start = init;
    for (int i = 0; i < n_nuis_modes; ++i) {
      start.q[i] += best.dq[i] * nq_scale[i];
      start.v[i] += best.dv[i] * nv_scale[i];
    }
    ForwardBatch batch;
    batch.n_sets = 1;
    batch.params = full;
    batch.initial = std::span<const ModalState>(&start, 1);
    batch.want_force = batch.want_end_state = true;
    backend_->solve(problem, batch, fwd);
    est.forward_solves += 1;
    const ForceParams fp = force_params_from(space.model(), full);
    double peak = 0, mean = 0, indent = 0;
    for (int n = 0; n < N; ++n) {
      const double f = fwd.force_n[n];
      peak = std::max(peak, -f);
      mean += f;
      indent = std::max(indent, indentation_m(space.model(), fp, fwd.tip_z_m[n]));
    }
    est.peak_force_n = peak;
    est.mean_force_n = mean / N;
    est.max_indentation_m = indent;
    // Work taken by the tip-sample force over the last whole number of drive periods, per period:
    // over whole periods the elastic part returns what it stored and only the dissipated part
    // stays (over a window cut mid-contact, stored energy would masquerade as dissipation).
    const double drive_hz = FullParams(ParameterLayout(space.model()), full).drive(DriveParameter::frequency_hz);
    const double period_samples = drive_hz > 0 ? 1.0 / (drive_hz * w.sample_period_s) : 0.0;
    const int periods = period_samples > 0 ? static_cast<int>((N - 1) / period_samples) : 0;
    const int first = periods > 0 ? N - 1 - static_cast<int>(std::lround(periods * period_samples)) : 0;
    double work = 0;
    for (int n = std::max(first, 0); n + 1 < N; ++n)
      work -= 0.5 * (fwd.force_n[n] + fwd.force_n[n + 1]) * (fwd.tip_z_m[n + 1] - fwd.tip_z_m[n]);
    est.dissipated_energy_j = periods > 0 ? work / periods : work;
    previous_end_state_ = fwd.end_state[0];
    previous_end_t_s_ = w.t0_s + N * w.sample_period_s;
    previous_full_ = full;
    have_end_state_ = true;
    // How uncertain that end state is (modes 1-2, physical units): the next window inherits it,
    // through the end-state sensitivities of the polish's last linearisation (at this point).
    previous_end_cov_.resize(0, 0);
    if (np > 0 && full_cov_x.rows() == np && full_cov_x.allFinite() && J_end.cols() == np && J_end.allFinite())
      previous_end_cov_ = J_end * full_cov_x * J_end.transpose();
  }

  bool singular_only = false;  // not converged only because an unknown is undetermined
  if (!std::isfinite(best_cost)) {
    est.status = EstimateStatus::not_converged;
    note = "no parameter set in the bounds gave a finite misfit; " + note;
  } else if (m > 0 && (!identifiable || !std::all_of(est.sigma.begin(), est.sigma.end(), [](double s) { return std::isfinite(s); }))) {
    est.status = EstimateStatus::not_converged;
    singular_only = est.misfit <= opt.max_misfit;
  } else if (est.misfit > opt.max_misfit) {
    est.status = EstimateStatus::not_converged;
    note = "relative misfit " + std::to_string(est.misfit) + " above " + std::to_string(opt.max_misfit) +
           ": the model does not explain the window; " + note;
  }
  if (!note.empty()) est.message = note.substr(0, note.size() - 2);
  if (est.status == EstimateStatus::ok) {
    previous_values_ = values;
    previous_sigma_ = est.sigma;
    previous_misfit_ = est.misfit;
    previous_noise_var_m2_ = noise_var_m2;
  } else {
    // Do not seed the next pixel from a fit we do not trust, nor give its end state a prior. A fit
    // that explains the window but leaves an unknown undetermined (a contact so light that the
    // estimate just misses the surface) keeps the last trusted warm start: without it, the next
    // window's cold swarm on two drive periods can settle in a wrong basin that fits as well.
    previous_end_cov_.resize(0, 0);
    if (!singular_only) {
      previous_values_.clear();
      previous_sigma_.clear();
      // Nor continue from its end state (SPEC 5: a NOT_CONVERGED fit never seeds the next window):
      // the next window starts unknown.
      have_end_state_ = false;
    }
  }
  return finish(est);
}

}  // namespace tipforce
