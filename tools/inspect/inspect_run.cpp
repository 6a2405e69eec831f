#include "inspect_run.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <memory>

#include "tipforce/config.hpp"
#include "tipforce/event_log.hpp"
#include "tipforce/force_estimate_t.hpp"
#include "tipforce/lcm_convert.hpp"
#include "tipforce/reference.hpp"
#include "tipforce/tipforce.hpp"

namespace tipforce::inspect {
namespace {

// The pixel's window from the windows log: the last one of the probe at that pixel.
// `damage` receives a line per damaged stretch of the log that was skipped.
lcmio::DecodedWindow find_window(const InspectOptions& o, std::string& probe, std::vector<std::string>& damage) {
  std::optional<lcmio::LogReader> log;
  try {
    log.emplace(o.in);
  } catch (const lcmio::LogError& e) {
    throw InspectError(e.what());
  }
  std::map<std::string, lcmio::DecodedWindow> at_pixel;  // per probe
  std::size_t windows = 0;
  auto collect_damage = [&] {
    for (const auto& d : log->take_damage()) damage.push_back(lcmio::describe(d));
  };
  while (auto ev = log->next()) {
    collect_damage();
    lcmio::DecodedWindow d = lcmio::decode_window(ev->data.data(), ev->data.size());
    if (!d.attributable) continue;
    ++windows;
    if (d.header.pixel_x == o.pixel_x && d.header.pixel_y == o.pixel_y && (o.probe.empty() || d.header.probe == o.probe))
      at_pixel[d.header.probe] = std::move(d);
  }
  collect_damage();
  const std::string px = std::to_string(o.pixel_x) + "," + std::to_string(o.pixel_y);
  const std::string damaged =
      damage.empty() ? std::string()
                     : "; but the log is damaged (" + std::to_string(damage.size()) + " stretch" +
                           (damage.size() == 1 ? "" : "es") + " skipped, the first: " + damage.front() +
                           "), and the window may have been there";
  if (windows == 0) {
    if (!damaged.empty()) throw InspectDamagedError(o.in + " holds no readable deflection_window_t" + damaged);
    throw InspectError(o.in + " holds no deflection_window_t");
  }
  if (at_pixel.empty()) {
    const std::string what = o.in + " has no window at pixel " + px + (o.probe.empty() ? "" : " of probe " + o.probe);
    if (!damaged.empty()) throw InspectDamagedError(what + damaged);
    throw InspectError(what);
  }
  if (at_pixel.size() > 1) {
    std::string list;
    for (const auto& [name, _] : at_pixel) list += (list.empty() ? "" : ", ") + name;
    throw InspectError(o.in + " has windows of several probes at pixel " + px + " (" + list + "); choose one with --probe");
  }
  probe = at_pixel.begin()->first;
  lcmio::DecodedWindow d = std::move(at_pixel.begin()->second);
  if (d.error.empty())
    if (auto problem = window_problem(d.window)) d.error = *problem;
  if (!d.error.empty()) throw InspectError(o.in + ": the window at pixel " + px + " is malformed: " + d.error);
  return d;
}

// The pixel's estimate from an estimates log, or nullopt when none names it.
std::optional<force_estimate_t> find_estimate(const std::string& path, const std::string& probe, int x, int y) {
  std::optional<lcmio::LogReader> log;
  try {
    log.emplace(path);
  } catch (const lcmio::LogError& e) {
    throw InspectError(e.what());
  }
  std::optional<force_estimate_t> found;
  while (auto ev = log->next()) {
    force_estimate_t e;
    if (ev->data.empty() || e.decode(ev->data.data(), 0, static_cast<int>(ev->data.size())) < 0) continue;
    if (e.probe == probe && e.pixel_x == x && e.pixel_y == y) found = e;
  }
  return found;
}

double relative_misfit(const std::vector<double>& measured, const std::vector<double>& fitted) {
  double r2 = 0, u2 = 0;
  for (std::size_t i = 0; i < measured.size(); ++i) {
    r2 += (measured[i] - fitted[i]) * (measured[i] - fitted[i]);
    u2 += measured[i] * measured[i];
  }
  return u2 > 0 ? std::sqrt(r2 / u2) : std::numeric_limits<double>::quiet_NaN();
}

// The settled tapping state at the window's first sample: the drive's linear steady state six
// decay times of mode 1 earlier, run in with the estimate's force. A fit's own start also carries
// what the window before it left ringing; in steady tapping the two agree, and the report gives
// both misfits so that a difference shows.
ModalState settled_start(ForwardBackend& backend, const ProbeModel& probe, const Window& w,
                         const std::vector<double>& full, std::string& note) {
  const ModalModel& modal = probe.modal;
  if (w.drive.kind == DriveKind::sampled) {
    note = "sampled drive: no base motion before the window, the fit is drawn from rest";
    return ModalState::rest(modal.n_modes());
  }
  const ParameterLayout layout(probe.space.model());
  const double a = full[layout.drive_index(DriveParameter::amplitude_m)];
  const double f = full[layout.drive_index(DriveParameter::frequency_hz)];
  const double phase = full[layout.drive_index(DriveParameter::phase_rad)];
  const double tau_s = 2 * modal.modes()[0].quality_factor / modal.modes()[0].omega_rad_per_s;
  const int lead = static_cast<int>(std::min(6 * tau_s / w.sample_period_s, 400000.0));
  Window run = w;
  run.initial = InitialState::rest;
  run.t0_s = w.t0_s - lead * w.sample_period_s;
  run.deflection_m.assign(static_cast<std::size_t>(lead), 0.0);
  if (w.drive.kind == DriveKind::chirp) note = "chirp: the run-in starts from the sine steady state at its start frequency";
  return simulate_one(backend, modal, probe.space.model(), run, full, linear_steady_state(modal, a, f, phase, run.t0_s))
      .end_state[0];
}

// The start state that best explains the window with the estimate held fixed: Gauss-Newton on
// the displacement and velocity of modes 1 and 2 at the first sample (the four start unknowns the
// inversion fits too), from the settled state. In a scan the cantilever still rings from the
// pixels before (mode 1 decays over some 15 windows in the demo), so the settled state alone
// misses the data by far more than the fit did.
ModalState fitted_start(ForwardBackend& backend, const ProbeModel& probe, const Window& w,
                        const std::vector<double>& full, ModalState start, double& cost, int iterations = 60) {
  const ModalModel& modal = probe.modal;
  const int substeps = default_substeps(probe.space.model());
  const StepCoefficients step = make_step_coefficients(modal, w.sample_period_s / substeps);
  const int m = std::min(2, modal.n_modes());
  const std::size_t N = w.deflection_m.size();
  const int k = 2 * m;
  double scale = 0;
  for (double u : w.deflection_m) scale = std::max(scale, std::abs(u));
  scale = std::max(scale, 1e-12);
  std::vector<double> dq(static_cast<std::size_t>(k));
  for (int i = 0; i < m; ++i) {
    dq[static_cast<std::size_t>(2 * i)] = 1e-4 * scale;
    dq[static_cast<std::size_t>(2 * i + 1)] = 1e-4 * scale * modal.modes()[static_cast<std::size_t>(i)].omega_rad_per_s;
  }
  auto shifted = [&](const ModalState& s, const Eigen::VectorXd& c) {
    ModalState out = s;
    for (int i = 0; i < m; ++i) {
      out.q[static_cast<std::size_t>(i)] += c(2 * i);
      out.v[static_cast<std::size_t>(i)] += c(2 * i + 1);
    }
    return out;
  };
  auto solve = [&](const std::vector<ModalState>& starts, ForwardOutput& res) {
    // Structure of arrays: parameter k of set s at k * n_sets + s (ForwardBatch).
    std::vector<double> params;
    for (double v : full) params.insert(params.end(), starts.size(), v);
    ForwardBatch batch;
    batch.n_sets = static_cast<int>(starts.size());
    batch.params = params;
    batch.initial = starts;
    batch.want_signal = true;
    backend.solve(ForwardProblem{&modal, &step, probe.space.model(), &w, substeps}, batch, res);
  };
  ForwardOutput res;
  solve({start}, res);
  cost = res.cost[0];
  double lambda = 1e-3;
  for (int it = 0; it < iterations; ++it) {
    std::vector<ModalState> starts{start};
    for (int j = 0; j < k; ++j) {
      Eigen::VectorXd c = Eigen::VectorXd::Zero(k);
      c(j) = dq[static_cast<std::size_t>(j)];
      starts.push_back(shifted(start, c));
    }
    solve(starts, res);
    Eigen::MatrixXd J(static_cast<Eigen::Index>(N), k);
    Eigen::VectorXd r(static_cast<Eigen::Index>(N));
    for (std::size_t n = 0; n < N; ++n) {
      r(static_cast<Eigen::Index>(n)) = w.deflection_m[n] - res.signal[n];
      for (int j = 0; j < k; ++j)
        J(static_cast<Eigen::Index>(n), j) =
            (res.signal[static_cast<std::size_t>(j + 1) * N + n] - res.signal[n]) / dq[static_cast<std::size_t>(j)];
    }
    // Levenberg-Marquardt: contact makes the response to the start nonlinear, and a plain
    // Gauss-Newton step often overshoots it.
    const Eigen::MatrixXd JtJ = J.transpose() * J;
    const Eigen::VectorXd Jtr = J.transpose() * r;
    bool improved = false;
    for (int tries = 0; tries < 12 && !improved; ++tries) {
      Eigen::MatrixXd A = JtJ;
      for (int j = 0; j < k; ++j) A(j, j) *= 1 + lambda;
      const Eigen::VectorXd c = A.ldlt().solve(Jtr);
      const ModalState trial = shifted(start, c);
      ForwardOutput t;
      solve({trial}, t);
      if (t.cost[0] < cost) {
        improved = true;
        const bool small = cost - t.cost[0] < 1e-6 * cost;
        cost = t.cost[0];
        start = trial;
        lambda = std::max(lambda / 3, 1e-9);
        if (small) return start;
      } else {
        lambda *= 8;
      }
    }
    if (!improved) break;
  }
  return start;
}

// `s` with mode 1 moved so that the measured signal's value and slope at the first sample (a
// quadratic fitted over an eighth of mode 1's period) are matched, the other modes kept.
ModalState matched_to_first_samples(const ModalModel& modal, const Window& w, ModalState s) {
  const double period = 1.0 / modal.modes()[0].frequency_hz;
  const int k = std::clamp(static_cast<int>(period / (8 * w.sample_period_s)), 3, w.n_samples());
  Eigen::MatrixXd A(k, 3);
  Eigen::VectorXd b(k);
  for (int i = 0; i < k; ++i) {
    const double t = i * w.sample_period_s;
    A.row(i) << 1.0, t, t * t;
    b(i) = w.deflection_m[static_cast<std::size_t>(i)];
  }
  const Eigen::Vector3d c = A.colPivHouseholderQr().solve(b);
  double s0 = 0, s1 = 0;
  for (int i = 1; i < modal.n_modes(); ++i) {
    s0 += modal.sensor_gain(i) * s.q[static_cast<std::size_t>(i)];
    s1 += modal.sensor_gain(i) * s.v[static_cast<std::size_t>(i)];
  }
  s.q[0] = (c(0) - s0) / modal.sensor_gain(0);
  s.v[0] = (c(1) - s1) / modal.sensor_gain(0);
  return s;
}

// The best of the start fits from a few guesses: the settled state, it matched to the first
// samples, and the drive's linear steady state matched to them (the inversion's own guess for
// an unknown start). Contact makes the misfit over the start non-convex.
ModalState best_start(ForwardBackend& backend, const ProbeModel& probe, const Window& w, const std::vector<double>& full,
                      std::string& note) {
  const ModalState settled = settled_start(backend, probe, w, full, note);
  std::vector<ModalState> guesses{settled, matched_to_first_samples(probe.modal, w, settled)};
  if (w.drive.kind != DriveKind::sampled) {
    const ParameterLayout layout(probe.space.model());
    guesses.push_back(matched_to_first_samples(
        probe.modal, w,
        linear_steady_state(probe.modal, full[layout.drive_index(DriveParameter::amplitude_m)],
                            full[layout.drive_index(DriveParameter::frequency_hz)],
                            full[layout.drive_index(DriveParameter::phase_rad)], w.t0_s)));
  }
  ModalState best = settled;
  double best_cost = std::numeric_limits<double>::infinity();
  for (const auto& g : guesses) {
    double cost = 0;
    ModalState s = fitted_start(backend, probe, w, full, g, cost);
    if (cost < best_cost) best_cost = cost, best = std::move(s);
  }
  return best;
}

}  // namespace

InspectReport run_inspect(const InspectOptions& o, std::ostream& out) {
  Config config;
  try {
    config = load_config(o.config);
  } catch (const ConfigError& e) {
    throw InspectError(std::string("config error: ") + e.what());
  }
  InspectReport rep;
  std::vector<std::string> damage;
  lcmio::DecodedWindow decoded = find_window(o, rep.probe, damage);
  if (!config.probes.count(rep.probe)) throw InspectError(o.config + ": probe." + rep.probe + ": no such probe");
  const ProbeModel probe = config.probe_model(rep.probe);
  const ParameterSpace& space = probe.space;
  rep.model = std::string(to_string(space.model()));
  rep.names = space.unknown_names();
  const int n = space.n_unknowns();
  Window w = decoded.window;
  // A lone window has no previous fit to continue from.
  if (w.initial == InitialState::continued) w.initial = InitialState::unknown;

  auto backend = make_cpu_backend();
  Inverter inverter(probe, *backend);
  const Estimate refit = inverter.invert(w);
  rep.values = refit.values;
  rep.sigma = refit.sigma;
  rep.estimate_misfit = refit.misfit;
  rep.source = "refit";
  std::vector<std::string> notes;
  for (const auto& d : damage) notes.push_back(o.in + " is damaged elsewhere: " + d + " (this pixel's window was read whole)");
  if (refit.status != EstimateStatus::ok) notes.push_back("the refit is not OK: " + refit.message);
  Eigen::MatrixXd corr = Eigen::MatrixXd::Identity(n, n);
  if (refit.covariance.rows() == n)
    for (int i = 0; i < n; ++i)
      for (int j = 0; j < n; ++j) {
        const double d = std::sqrt(refit.covariance(i, i) * refit.covariance(j, j));
        corr(i, j) = d > 0 && std::isfinite(d) ? refit.covariance(i, j) / d : (i == j ? 1.0 : 0.0);
      }

  if (!o.estimates.empty()) {
    const auto e = find_estimate(o.estimates, rep.probe, o.pixel_x, o.pixel_y);
    const std::string px = std::to_string(o.pixel_x) + "," + std::to_string(o.pixel_y);
    if (!e) throw InspectError(o.estimates + " has no estimate of probe " + rep.probe + " at pixel " + px);
    // The estimate must answer this window, not the same pixel of another scan (it was drawn
    // against this window's data without a word, its misfit 40 x the curve's).
    if (e->seq != decoded.header.seq || e->utime != decoded.header.utime)
      throw InspectError(o.estimates + ": the estimate at pixel " + px + " answers window seq " + std::to_string(e->seq) +
                         " (utime " + std::to_string(e->utime) + "), but the window there in " + o.in + " is seq " +
                         std::to_string(decoded.header.seq) + " (utime " + std::to_string(decoded.header.utime) +
                         "): estimates of another scan?");
    if (e->status == force_estimate_t::STATUS_REJECTED)
      throw InspectError(o.estimates + ": the estimate at pixel " + px + " was rejected: " + e->message);
    for (int i = 0; i < n; ++i) {
      const auto it = std::find(e->param_names.begin(), e->param_names.end(), rep.names[static_cast<std::size_t>(i)]);
      if (it == e->param_names.end())
        throw InspectError(o.estimates + ": the estimate at pixel " + px + " has no " + rep.names[static_cast<std::size_t>(i)] +
                           " (estimated with another configuration?)");
      const auto k = static_cast<std::size_t>(it - e->param_names.begin());
      rep.values[static_cast<std::size_t>(i)] = e->params[k];
      rep.sigma[static_cast<std::size_t>(i)] = e->param_sigma[k];
    }
    rep.estimate_misfit = e->misfit;
    rep.source = o.estimates;
    notes.push_back("values and sigmas from " + o.estimates + "; correlations from a refit of the window");
  }

  std::vector<double> full(static_cast<std::size_t>(space.n_full()));
  space.assemble(w, rep.values.data(), full.data());
  std::string note;
  const ModalState start = best_start(*backend, probe, w, full, note);
  rep.full = full;
  rep.start_q = start.q;
  rep.start_v = start.v;
  if (!note.empty()) notes.push_back(note);
  const ForwardOutput fit = simulate_one(*backend, probe.modal, space.model(), w, full, start);
  const std::size_t N = w.deflection_m.size();
  Curves& c = rep.curves;
  for (std::size_t i = 0; i < N; ++i) {
    c.t_s.push_back(w.t0_s + static_cast<double>(i) * w.sample_period_s);
    c.measured_m.push_back(w.deflection_m[i]);
    c.fitted_m.push_back(fit.signal[i]);
    c.residual_m.push_back(w.deflection_m[i] - fit.signal[i]);
    c.force_n.push_back(fit.force_n[i]);
    c.tip_z_m.push_back(fit.tip_z_m[i]);
  }
  rep.curve_misfit = relative_misfit(c.measured_m, c.fitted_m);
  // Same seq and utime but another scan (two scans of one layout): only the misfits can tell.
  if (!o.estimates.empty() && !(std::abs(rep.curve_misfit - rep.estimate_misfit) <= 0.1 * rep.curve_misfit))
    notes.push_back("the reported misfit and the curve's differ by more than 10 %: is the estimate of this window "
                    "(an estimates log of another scan with the same layout)?");
  const int h_index = space.index_of("h_m");
  rep.h_m = h_index >= 0 ? full[static_cast<std::size_t>(h_index)] : std::numeric_limits<double>::quiet_NaN();

  // The misfit over the two most correlated unknowns, the others held at the estimate, every
  // point started from the estimate's settled state.
  Landscape& L = rep.landscape;
  if (n >= 1) {
    int a = 0, b = n >= 2 ? 1 : 0;
    for (int i = 0; i < n; ++i)
      for (int j = i + 1; j < n; ++j)
        if (std::abs(corr(i, j)) > std::abs(corr(a, b))) a = i, b = j;
    L.two_d = n >= 2;
    const auto& idx = space.unknown_index();
    auto axis = [&](int u, std::vector<double>& grid) {
      const double v = rep.values[static_cast<std::size_t>(u)];
      double s = rep.sigma[static_cast<std::size_t>(u)];
      if (!(s > 0) || !std::isfinite(s)) s = 0.05 * (space.upper()[static_cast<std::size_t>(u)] - space.lower()[static_cast<std::size_t>(u)]);
      const double lo = std::max(space.lower()[static_cast<std::size_t>(u)], v - o.landscape_sigmas * s);
      const double hi = std::min(space.upper()[static_cast<std::size_t>(u)], v + o.landscape_sigmas * s);
      for (int k = 0; k < o.landscape_points; ++k) grid.push_back(lo + (hi - lo) * k / (o.landscape_points - 1));
    };
    L.x_name = rep.names[static_cast<std::size_t>(a)];
    axis(a, L.x);
    L.x_est = rep.values[static_cast<std::size_t>(a)];
    L.sx = rep.sigma[static_cast<std::size_t>(a)];
    if (L.two_d) {
      L.y_name = rep.names[static_cast<std::size_t>(b)];
      axis(b, L.y);
      L.y_est = rep.values[static_cast<std::size_t>(b)];
      L.sy = rep.sigma[static_cast<std::size_t>(b)];
      L.rho = corr(a, b);
    } else {
      L.y = {0.0};
    }
    const int sets = static_cast<int>(L.x.size() * L.y.size());
    // Structure of arrays: parameter k of set s at k * n_sets + s (ForwardBatch).
    std::vector<double> params(static_cast<std::size_t>(sets) * full.size());
    const auto ia = static_cast<std::size_t>(idx[static_cast<std::size_t>(a)]);
    const auto ib = static_cast<std::size_t>(idx[static_cast<std::size_t>(b)]);
    for (std::size_t iy = 0, set = 0; iy < L.y.size(); ++iy)
      for (std::size_t ix = 0; ix < L.x.size(); ++ix, ++set)
        for (std::size_t k = 0; k < full.size(); ++k)
          params[k * static_cast<std::size_t>(sets) + set] =
              k == ia ? L.x[ix] : (L.two_d && k == ib) ? L.y[iy] : full[k];
    const std::vector<ModalState> starts(static_cast<std::size_t>(sets), start);
    const int substeps = default_substeps(space.model());
    const StepCoefficients step = make_step_coefficients(probe.modal, w.sample_period_s / substeps);
    ForwardBatch batch;
    batch.n_sets = sets;
    batch.params = params;
    batch.initial = starts;
    ForwardOutput res;
    backend->solve(ForwardProblem{&probe.modal, &step, space.model(), &w, substeps}, batch, res);
    double u2 = 0;
    for (double u : w.deflection_m) u2 += u * u;
    for (double cost : res.cost) L.misfit.push_back(std::sqrt(cost / u2));
  }

  out << "tipforce inspect: pixel " << o.pixel_x << "," << o.pixel_y << " of probe " << rep.probe << " (model " << rep.model
      << ", " << N << " samples)\n";
  for (int i = 0; i < n; ++i)
    out << "  " << rep.names[static_cast<std::size_t>(i)] << " = " << rep.values[static_cast<std::size_t>(i)] << " +- "
        << rep.sigma[static_cast<std::size_t>(i)] << " (1 sigma, " << rep.source << ")\n";
  out << "  misfit: " << rep.estimate_misfit << " reported, " << rep.curve_misfit
      << " of the curve drawn (its start state fitted with the estimate held)\n";
  for (const auto& nt : notes) out << "  note: " << nt << "\n";
  return rep;
}

}  // namespace tipforce::inspect
