// The setpoint advisor: predictions of the next window's peak force from one window's fit.
#include "tipforce/setpoint_advisor.hpp"

#include <algorithm>
#include <cmath>
#include <sstream>

#include <Eigen/Eigenvalues>

#include "tipforce/assert.hpp"
#include "tipforce/parameter_layout.hpp"
#include "tipforce/forward.hpp"

namespace tipforce {
namespace {

std::string format_n(double force_n) {
  std::ostringstream o;
  o.precision(3);
  o << force_n * 1e9 << " nN";
  return o.str();
}
std::string format_m(double length_m) {
  std::ostringstream o;
  o.precision(3);
  o << length_m * 1e9 << " nm";
  return o.str();
}

double peak_repulsive_force(std::span<const double> force_n) {
  double peak = 0;
  for (double f : force_n) peak = std::max(peak, -f);
  return peak;
}

}  // namespace

double free_amplitude_per_drive_amplitude(const ModalModel& modal, double frequency_hz) {
  TIPFORCE_THROW_UNLESS(frequency_hz > 0 && std::isfinite(frequency_hz), "the drive frequency must be positive");
  // The steady state's signal a quarter period apart: its two quadratures.
  const ModalState s0 = linear_steady_state(modal, 1.0, frequency_hz, 0.0, 0.0);
  const ModalState s1 = linear_steady_state(modal, 1.0, frequency_hz, 0.0, 0.25 / frequency_hz);
  double u0 = 0, u1 = 0;
  for (int i = 0; i < modal.n_modes(); ++i) {
    u0 += modal.sensor_gain(i) * s0.q[static_cast<std::size_t>(i)];
    u1 += modal.sensor_gain(i) * s1.q[static_cast<std::size_t>(i)];
  }
  return std::hypot(u0, u1);
}

std::string advisor_options_problem(const AdvisorOptions& o) {
  if (!(o.max_peak_force_n > 0) || !std::isfinite(o.max_peak_force_n)) return "max_peak_force_n must be positive";
  if (!(o.margin >= 0 && o.margin < 1)) return "margin must be in [0, 1)";
  if (!(o.sigma_multiplier >= 0 && o.sigma_multiplier <= 10)) return "sigma_multiplier must be in [0, 10]";
  if (!std::isnan(o.min_free_amplitude_m) && !(o.min_free_amplitude_m > 0 && std::isfinite(o.min_free_amplitude_m)))
    return "min_free_amplitude_m must be positive";
  if (!(o.max_z_step_m >= 0 && std::isfinite(o.max_z_step_m))) return "max_z_step_m must be >= 0";
  if (!(o.z_step_m > 0 && std::isfinite(o.z_step_m))) return "z_step_m must be positive";
  if (!(o.amplitude_step_rel > 0 && o.amplitude_step_rel < 0.5)) return "amplitude_step_rel must be in (0, 0.5)";
  if (o.max_iterations < 1 || o.max_iterations > 20) return "max_iterations must be in [1, 20]";
  if (!(o.aim_tolerance_rel > 0 && o.aim_tolerance_rel < 1)) return "aim_tolerance_rel must be in (0, 1)";
  return {};
}

// The forward solves of one advice: the next window from the fit's end state, at given setpoints,
// with the estimate's unknowns at their values or moved along the covariance's principal axes.
class SetpointAdvisor::Solver {
 public:
  // With propagate = false the estimate's uncertainty is left out (sigma 0).
  Solver(const SetpointAdvisor& advisor, const FittedWindow& fit, ForwardBackend& backend,
         const StepCoefficients& step, bool propagate)
      : fit_(fit), backend_(backend), layout_(advisor.space_.model()) {
    const Window& w = *fit.window;
    next_.initial = InitialState::continued;
    next_.t0_s = fit.end_t_s;
    next_.sample_period_s = w.sample_period_s;
    next_.drive = w.drive;
    next_.deflection_m.assign(w.deflection_m.size(), 0.0);  // the cost against it is not used
    problem_ = ForwardProblem{&advisor.modal_, &step, advisor.space_.model(), &next_, 1};
    h_index_ = advisor.space_.index_of("h_m");
    amplitude_index_ = layout_.drive_index(DriveParameter::amplitude_m);
    if (propagate) make_axes(advisor.space_);
  }

  double drive_amplitude_m() const { return fit_.full_params[static_cast<std::size_t>(amplitude_index_)]; }
  int forward_solves() const { return solves_; }

  // The peak force at the setpoints and its 1-sigma.
  Prediction predict(double drive_amplitude_m, double z_offset_m) {
    std::vector<std::vector<double>> sets = with_axes(full_at(drive_amplitude_m, z_offset_m));
    return from_peaks(peaks(sets));
  }

  // The hold prediction and the sensitivities to both setpoints there, in one batch.
  struct Hold {
    Prediction at;
    double dpeak_ddrive = 0, dpeak_dz = 0;
  };
  Hold hold(double z_step_m, double drive_step_m) {
    const double a = drive_amplitude_m();
    std::vector<std::vector<double>> sets = with_axes(full_at(a, 0));
    const std::size_t first_extra = sets.size();
    sets.push_back(full_at(a, z_step_m));
    sets.push_back(full_at(a, -z_step_m));
    sets.push_back(full_at(a + drive_step_m, 0));
    sets.push_back(full_at(a - drive_step_m, 0));
    const std::vector<double> peak = peaks(sets);
    Hold h;
    h.at = from_peaks(std::span<const double>(peak.data(), first_extra));
    h.dpeak_dz = (peak[first_extra] - peak[first_extra + 1]) / (2 * z_step_m);
    h.dpeak_ddrive = (peak[first_extra + 2] - peak[first_extra + 3]) / (2 * drive_step_m);
    return h;
  }

 private:
  // One principal axis of the estimate's covariance: a step of one standard deviation along it
  // (in the full vector's unknowns), and the fractions of it that stay inside the bounds.
  struct Axis {
    std::vector<double> step;  // per unknown
    double up = 1, down = 1;   // in (0, 1]; 0: that side leaves the bounds at once
  };

  // Along the principal axes rather than one unknown at a time: where two unknowns trade off
  // (k and h of a light contact), the data fix the force along their valley and leave it free
  // across it, and only the axes see that; a step of one sigma in k alone leaves the valley and
  // reads as an uncertainty the data do not have.
  void make_axes(const ParameterSpace& space) {
    const Estimate& e = *fit_.estimate;
    const auto& idx = space.unknown_index();
    const int m = static_cast<int>(idx.size());
    if (m == 0 || e.covariance.rows() != m || e.covariance.cols() != m || !e.covariance.allFinite()) return;
    const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(e.covariance);
    if (eig.info() != Eigen::Success) return;
    for (int i = 0; i < m; ++i) {
      const double lambda = eig.eigenvalues()(i);
      if (!(lambda > 0)) continue;
      Axis axis;
      axis.step.resize(static_cast<std::size_t>(m));
      for (int j = 0; j < m; ++j) axis.step[static_cast<std::size_t>(j)] = std::sqrt(lambda) * eig.eigenvectors()(j, i);
      for (int j = 0; j < m; ++j) {
        const double v = fit_.full_params[static_cast<std::size_t>(idx[static_cast<std::size_t>(j)])];
        const double d = axis.step[static_cast<std::size_t>(j)];
        if (d == 0) continue;
        const double to_hi = space.upper()[static_cast<std::size_t>(j)] - v, to_lo = v - space.lower()[static_cast<std::size_t>(j)];
        axis.up = std::min(axis.up, std::max(0.0, (d > 0 ? to_hi : to_lo) / std::abs(d)));
        axis.down = std::min(axis.down, std::max(0.0, (d > 0 ? to_lo : to_hi) / std::abs(d)));
      }
      if (axis.up > 0 || axis.down > 0) axes_.push_back(std::move(axis));
    }
    unknown_index_ = idx;
  }

  std::vector<std::vector<double>> with_axes(std::vector<double> centre) const {
    std::vector<std::vector<double>> sets{std::move(centre)};
    for (const Axis& axis : axes_)
      for (double t : {axis.up, -axis.down}) {
        sets.push_back(sets.front());
        for (std::size_t j = 0; j < unknown_index_.size(); ++j)
          sets.back()[static_cast<std::size_t>(unknown_index_[j])] += t * axis.step[j];
      }
    return sets;
  }

  std::vector<double> full_at(double drive_amplitude_m, double z_offset_m) const {
    std::vector<double> full(fit_.full_params.begin(), fit_.full_params.end());
    full[static_cast<std::size_t>(h_index_)] += z_offset_m;
    full[static_cast<std::size_t>(amplitude_index_)] = drive_amplitude_m;
    return full;
  }

  std::vector<double> peaks(const std::vector<std::vector<double>>& sets) {
    const int n_sets = static_cast<int>(sets.size());
    const int n_full = layout_.n_full();
    std::vector<double> soa(static_cast<std::size_t>(n_sets * n_full));
    for (int s = 0; s < n_sets; ++s)
      for (int k = 0; k < n_full; ++k)
        soa[static_cast<std::size_t>(k * n_sets + s)] = sets[static_cast<std::size_t>(s)][static_cast<std::size_t>(k)];
    ForwardBatch batch;
    batch.n_sets = n_sets;
    batch.params = soa;
    batch.initial = std::span<const ModalState>(fit_.end_state, 1);
    batch.drive_varies = true;
    batch.want_force = true;
    ForwardOutput out;
    backend_.solve(problem_, batch, out);
    solves_ += n_sets;
    const std::size_t N = next_.deflection_m.size();
    std::vector<double> peak(static_cast<std::size_t>(n_sets));
    for (int s = 0; s < n_sets; ++s)
      peak[static_cast<std::size_t>(s)] =
          peak_repulsive_force(std::span<const double>(out.force_n.data() + static_cast<std::size_t>(s) * N, N));
    return peak;
  }

  // Along each axis (one sigma of a Gaussian direction): the first derivative's square is its
  // share of the variance (the delta method, g' C g, written in the axes), and the second
  // derivative H gives the quadratic term, whose spread adds 2 (H / 2)^2. Both from the centre
  // and the two points of the axis; one-sided where the bounds cut an axis off.
  Prediction from_peaks(std::span<const double> peak) const {
    Prediction pr;
    pr.peak_n = peak[0];
    double var = 0;
    for (std::size_t i = 0; i < axes_.size(); ++i) {
      const Axis& axis = axes_[i];
      const double up = peak[1 + 2 * i], down = peak[2 + 2 * i];
      double slope = 0;
      if (axis.up > 0 && axis.down > 0) {
        slope = (up - down) / (axis.up + axis.down);
        const double second = 2 * ((up - peak[0]) / axis.up - (peak[0] - down) / axis.down) / (axis.up + axis.down);
        var += 2 * std::pow(0.5 * second, 2);
      } else if (axis.up > 0) {
        slope = (up - peak[0]) / axis.up;
      } else {
        slope = (peak[0] - down) / axis.down;
      }
      var += slope * slope;
    }
    pr.sigma_n = std::sqrt(var);
    return pr;
  }

  const FittedWindow& fit_;
  ForwardBackend& backend_;
  ParameterLayout layout_;
  Window next_;
  ForwardProblem problem_;
  int h_index_ = -1, amplitude_index_ = -1;
  std::vector<int> unknown_index_;
  std::vector<Axis> axes_;
  int solves_ = 0;
};

SetpointAdvisor::SetpointAdvisor(const ModalModel& modal, const ParameterSpace& space, AdvisorOptions options)
    : modal_(modal), space_(space), options_(options) {
  const std::string problem = advisor_options_problem(options_);
  TIPFORCE_THROW_UNLESS(problem.empty(), problem);
  TIPFORCE_THROW_UNLESS(space_.index_of("h_m") >= 0, "the force model has no separation h_m to advise on");
}

Advice SetpointAdvisor::advise(const FittedWindow& fit, ForwardBackend& backend) {
  const AdvisorOptions& o = options_;
  Advice a;
  a.target_peak_force_n = aim_n();
  if (fit.estimate == nullptr || fit.window == nullptr) {
    a.reason = "no estimate";
    return a;
  }
  const Estimate& e = *fit.estimate;
  const Window& w = *fit.window;
  // A window in which the tip never touches fits without contact, and the contact's stiffness is
  // then undetermined, which makes the estimate NOT_CONVERGED. The fit still explains the window
  // (the inverter keeps its end state only then), and a contact that mattered would have
  // explained it better: the force is under any limit. Advised, so that a loop that has
  // retracted too far can come back; every other fit that is not OK predicts nothing.
  const bool contact_free = e.status == EstimateStatus::not_converged && e.peak_force_n == 0 && fit.end_state != nullptr;
  if (e.status != EstimateStatus::ok && !contact_free) {
    // A fit that is not trusted predicts nothing (SPEC 5: it never seeds the next window either).
    a.reason = std::string(e.status == EstimateStatus::rejected ? "estimate REJECTED" : "estimate NOT_CONVERGED") +
               ": no prediction, keep the setpoints (" + e.message + ")";
    return a;
  }
  if (w.drive.kind != DriveKind::sine) {
    a.reason = "the advisor needs a sine drive (a free amplitude belongs to one frequency, and a sampled drive's "
               "next window is unknown)";
    return a;
  }
  if (fit.end_state == nullptr || fit.full_params.size() != static_cast<std::size_t>(space_.n_full())) {
    a.reason = "the fit left no end state to predict the next window from";
    return a;
  }
  if (w.sample_period_s != step_dt_s_) {
    step_ = make_step_coefficients(modal_, w.sample_period_s);
    step_dt_s_ = w.sample_period_s;
  }
  // Without contact the data bound the separation from one side only (the tip came no nearer
  // than its deepest point), which no Gaussian describes: the prediction there is the fit's,
  // without an uncertainty from the estimate.
  Solver solver(*this, fit, backend, step_, !contact_free);
  const double drive_m = solver.drive_amplitude_m();
  const double frequency_hz = FullParams(ParameterLayout(space_.model()), fit.full_params).drive(DriveParameter::frequency_hz);
  const double gain = free_amplitude_per_drive_amplitude(modal_, frequency_hz);
  a.current_free_amplitude_m = drive_m * gain;
  a.free_amplitude_m = a.current_free_amplitude_m;
  a.separation_m = fit.full_params[static_cast<std::size_t>(space_.index_of("h_m"))];

  const auto hold = solver.hold(o.z_step_m, o.amplitude_step_rel * std::abs(drive_m));
  a.hold_peak_force_n = a.predicted_peak_force_n = hold.at.peak_n;
  a.hold_sigma_n = a.predicted_sigma_n = hold.at.sigma_n;
  a.dpeak_dz_n_per_m = hold.dpeak_dz;
  a.dpeak_dfree_amplitude_n_per_m = hold.dpeak_ddrive / gain;
  std::string note;
  if (contact_free)
    note = "; no contact in the answered window (NOT_CONVERGED only for its undetermined contact; no sigma)";
  if (!std::isfinite(hold.at.peak_n) || !std::isfinite(hold.at.sigma_n)) {
    a.status = AdviceStatus::no_advice;
    a.reason = "the prediction of the next window is not finite";
    a.forward_solves = solver.forward_solves();
    return a;
  }
  const double excess0 = excess(hold.at);
  if (excess0 <= 0) {
    a.status = AdviceStatus::under_limit;
    a.reason = "predicted " + format_n(hold.at.peak_n) + " +- " + format_n(hold.at.sigma_n) + " under the aim " +
               format_n(a.target_peak_force_n) + ": keep the setpoints" + note;
    a.forward_solves = solver.forward_solves();
    return a;
  }

  return correct(solver, hold.at, gain, std::move(a), note);
}

Advice SetpointAdvisor::correct(Solver& solver, const Prediction& hold, double gain, Advice a,
                                const std::string& note) const {
  const AdvisorOptions& o = options_;
  const double excess0 = excess(hold);
  const std::string over = "predicted " + format_n(hold.peak_n) + " +- " + format_n(hold.sigma_n) + " over the aim " +
                           format_n(a.target_peak_force_n);
  // The correction's path: retract and lower the free amplitude, each in proportion to the room
  // it has squared times how strongly it acts (the smallest change in units of each knob's
  // allowed room that gives the linearised reduction), each clipped to its room. A knob that
  // does not lower the force (or has no room) is left alone.
  const bool amplitude_allowed = !std::isnan(o.min_free_amplitude_m);
  const double room_z = o.max_z_step_m;
  const double room_a = amplitude_allowed ? std::max(0.0, a.current_free_amplitude_m - o.min_free_amplitude_m) : 0.0;
  const double gz = std::max(0.0, -a.dpeak_dz_n_per_m);                       // force drop per m of retraction
  const double ga = std::max(0.0, a.dpeak_dfree_amplitude_n_per_m);      // force drop per m of amplitude
  const double weight = room_z * room_z * gz * gz + room_a * room_a * ga * ga;
  if (!(weight > 0)) {
    a.status = AdviceStatus::out_of_range;
    a.reason = over + ", and the allowed setpoints do not lower it" + note;
    a.forward_solves = solver.forward_solves();
    return a;
  }
  // The iteration aims half its tolerance under the aim, so that it ends in [aim - tolerance, aim].
  const double tolerance = o.aim_tolerance_rel * o.max_peak_force_n;
  // s = 1: the linearised correction.
  const double dz_per_s = (excess0 + 0.5 * tolerance) * room_z * room_z * gz / weight;
  const double da_per_s = (excess0 + 0.5 * tolerance) * room_a * room_a * ga / weight;
  const auto setpoints_at = [&](double s) {
    return Setpoints{a.current_free_amplitude_m - std::min(room_a, s * da_per_s), std::min(room_z, s * dz_per_s)};
  };
  const double s_max = std::max(dz_per_s > 0 ? room_z / dz_per_s : 0.0, da_per_s > 0 ? room_a / da_per_s : 0.0);
  const auto predict_at = [&](double s) {
    const Setpoints sp = setpoints_at(s);
    return solver.predict(sp.free_amplitude_m / gain, sp.z_offset_m);
  };
  // Secant iteration on the excess, from the hold point (s = 0) and the linearised guess.
  double s_prev = 0, e_prev = excess0;
  double s = std::min(1.0, s_max);
  Prediction best_pred = hold;
  double best_s = 0, best_e = excess0;
  for (int it = 0; it < o.max_iterations; ++it) {
    const Prediction pred = predict_at(s);
    const double e_s = excess(pred);
    // Keep the point nearest the aim from below; until there is one, the one with the lowest excess.
    const bool better = (e_s <= 0 && (best_e > 0 || e_s > best_e)) || (best_e > 0 && e_s < best_e);
    if (better) {
      best_pred = pred;
      best_s = s;
      best_e = e_s;
    }
    if (e_s <= 0 && e_s >= -tolerance) break;
    if (e_s > 0 && s >= s_max) break;  // as far as the room goes, and still over
    const double slope = (e_s - e_prev) / (s - s_prev);
    double s_next = slope < 0 ? s - (e_s + 0.5 * tolerance) / slope : s * 2;  // not decreasing here: go further
    s_next = std::clamp(s_next, 0.0, s_max);
    if (s_next == s) break;
    s_prev = s;
    e_prev = e_s;
    s = s_next;
  }
  const Setpoints chosen = setpoints_at(best_s);
  a.free_amplitude_m = chosen.free_amplitude_m;
  a.z_offset_m = chosen.z_offset_m;
  a.predicted_peak_force_n = best_pred.peak_n;
  a.predicted_sigma_n = best_pred.sigma_n;
  a.forward_solves = solver.forward_solves();
  std::string change = "retract " + format_m(chosen.z_offset_m);
  if (chosen.free_amplitude_m != a.current_free_amplitude_m)
    change += ", free amplitude " + format_m(a.current_free_amplitude_m) + " -> " + format_m(chosen.free_amplitude_m);
  if (best_e <= 0) {
    a.status = AdviceStatus::correction;
    a.reason = over + ": " + change + " gives " + format_n(best_pred.peak_n) + " +- " + format_n(best_pred.sigma_n) + note;
  } else {
    a.status = AdviceStatus::out_of_range;
    a.reason = over + "; the allowed setpoints get only to " + format_n(best_pred.peak_n) + " +- " +
               format_n(best_pred.sigma_n) + " (" + change + ")" + note;
  }
  return a;
}

}  // namespace tipforce
