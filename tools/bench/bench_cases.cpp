#include "bench_cases.hpp"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <memory>
#include <numbers>
#include <random>
#include <stdexcept>

#include "tipforce/inversion.hpp"
#include "tipforce/reference.hpp"

namespace tipforce::bench {
namespace {

Window sine_window(int samples, double sample_period_s, double amplitude_m, double frequency_hz) {
  Window w;
  w.sample_period_s = sample_period_s;
  w.drive.amplitude_m = amplitude_m;
  w.drive.frequency_hz = frequency_hz;
  w.deflection_m.assign(static_cast<std::size_t>(samples), 0.0);
  return w;
}

double first_resonance_hz(const ModalModel& modal) { return modal.modes()[0].omega_rad_per_s / (2 * std::numbers::pi); }

// The structure-of-arrays parameters of a batch: set s is `set(s)`, a full parameter vector.
template <class SetOf>
std::vector<double> soa_of(int n_full, int batch, SetOf set) {
  std::vector<double> soa(static_cast<std::size_t>(n_full) * batch);
  for (int s = 0; s < batch; ++s) {
    const std::vector<double> p = set(s);
    for (int k = 0; k < n_full; ++k) soa[static_cast<std::size_t>(k) * batch + s] = p[static_cast<std::size_t>(k)];
  }
  return soa;
}

}  // namespace

ForwardCase::ForwardCase(std::string name, ForceModelKind model, Window window, ModalState start,
                         std::vector<double> central, int batch, std::vector<double> params_soa)
    : name_(std::move(name)),
      modal_(paper_probe_spec()),
      model_(model),
      window_(std::move(window)),
      start_(std::move(start)),
      step_(make_step_coefficients(modal_, window_.sample_period_s)),
      central_(std::move(central)),
      batch_(batch),
      params_soa_(std::move(params_soa)) {
  if (params_soa_.size() != central_.size() * static_cast<std::size_t>(batch_))
    throw std::logic_error("bench case " + name_ + ": parameters do not fill the batch");
}

ForwardBatch ForwardCase::forward_batch() const {
  ForwardBatch b;
  b.n_sets = batch_;
  b.params = params_soa_;
  b.initial = std::span<const ModalState>(&start_, 1);
  return b;
}

double ForwardCase::error_against_reference(ForwardBackend& backend) const {
  return relative_l2_error(simulate_one(backend, modal_, model_, window_, central_, start_).signal,
                           reference_simulate(modal_, model_, window_, central_, start_).signal);
}

std::string cpu_model_name() {
  std::ifstream in("/proc/cpuinfo");
  std::string line;
  while (std::getline(in, line))
    if (line.rfind("model name", 0) == 0) return line.substr(line.find(':') + 2);
  return "unknown CPU";
}

double drive_for_free_amplitude(const ModalModel& modal, double free_amplitude_m) {
  const double f1 = first_resonance_hz(modal);
  double unit_amp = 0;  // free tip amplitude per nm of drive: the largest displacement over a period
  for (int j = 0; j < 200; ++j) {
    const ModalState unit = linear_steady_state(modal, 1e-9, f1, 0.0, j / (200 * f1));
    double u = 0;
    for (int i = 0; i < modal.n_modes(); ++i) u += modal.modes()[i].phi_tip * unit.q[i];
    unit_amp = std::max(unit_amp, std::abs(u));
  }
  return 1e-9 * free_amplitude_m / unit_amp;
}

std::unique_ptr<ForwardCase> firm_tapping(int samples, double sample_period_s, int batch) {
  const ModalModel modal(paper_probe_spec());
  const double a = 2e-9, f = 25600.0, h = 25e-9;
  auto set = [&](int s) { return std::vector<double>{2.0 + 4.0 * s / batch, h, a, f, 0.0, 0.0}; };
  return std::make_unique<ForwardCase>("firm_tapping", ForceModelKind::spring,
                                       sine_window(samples, sample_period_s, a, f), linear_steady_state(modal, a, f, 0.0, 0.0),
                                       std::vector<double>{4.0, h, a, f, 0.0, 0.0}, batch, soa_of(6, batch, set));
}

std::unique_ptr<ForwardCase> issue8_tapping(int samples, double sample_period_s, int batch, double k_n_per_m) {
  const ModalModel modal(paper_probe_spec());
  const double f1 = first_resonance_hz(modal), a = drive_for_free_amplitude(modal, 45e-9), h = 20e-9;
  auto set = [&](int s) { return std::vector<double>{1.0 + 3.0 * s / batch, h, a, f1, 0.0, 0.0}; };
  return std::make_unique<ForwardCase>("issue8", ForceModelKind::spring, sine_window(samples, sample_period_s, a, f1),
                                       linear_steady_state(modal, a, f1, 0.0, 0.0),
                                       std::vector<double>{k_n_per_m, h, a, f1, 0.0, 0.0}, batch, soa_of(6, batch, set));
}

std::unique_ptr<ForwardCase> cold_grid(double sample_period_s) {
  const ModalModel modal(paper_probe_spec());
  const double f1 = first_resonance_hz(modal), a = drive_for_free_amplitude(modal, 45e-9), reach = 45e-9;
  const InversionOptions options;
  const std::vector<double>& fractions = options.cold_physics_indentation_fractions;
  const int H = static_cast<int>(fractions.size()), batch = options.cold_physics_grid * H;
  const int samples = static_cast<int>(std::ceil(options.grid_periods / (f1 * sample_period_s)));
  auto set = [&](int c) {
    const double k = 0.1 * std::pow(200.0, (c / H + 0.5) / options.cold_physics_grid);
    return std::vector<double>{k, reach * (1 - fractions[static_cast<std::size_t>(c % H)]), a, f1, 0.0, 0.0};
  };
  auto c = std::make_unique<ForwardCase>("cold_grid", ForceModelKind::spring,
                                         sine_window(samples, sample_period_s, a, f1),
                                         linear_steady_state(modal, a, f1, 0.0, 0.0), set(0), batch,
                                         soa_of(6, batch, set));
  c->set_resolution(options.search_contact_rad_per_substep, options.search_crossing_rad_per_substep);
  return c;
}

std::unique_ptr<ForwardCase> scattered_search(int samples, double sample_period_s, int batch) {
  const ModalModel modal(paper_probe_spec());
  const double f1 = first_resonance_hz(modal), a = drive_for_free_amplitude(modal, 45e-9);
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<std::vector<double>> sets;
  for (int s = 0; s < batch; ++s) {
    const double k = 0.5 * std::pow(40.0, u(rng)), h = 10e-9 + 30e-9 * u(rng);
    sets.push_back({k, h, a, f1, 0.0, 0.0});
  }
  auto c = std::make_unique<ForwardCase>("scattered_search", ForceModelKind::spring,
                                         sine_window(samples, sample_period_s, a, f1),
                                         linear_steady_state(modal, a, f1, 0.0, 0.0), sets[0], batch,
                                         soa_of(6, batch, [&](int s) { return sets[static_cast<std::size_t>(s)]; }));
  const InversionOptions options;
  c->set_resolution(options.search_contact_rad_per_substep, options.search_crossing_rad_per_substep);
  return c;
}

std::vector<std::unique_ptr<ForwardCase>> work_precision_cases(int batch) {
  struct Model {
    ForceModelKind model;
    std::vector<double> params;  // h_m set from the amplitude
    int h_index;
  };
  const std::vector<Model> models = {{ForceModelKind::spring, {4.0, 0.0}, 1},
                                     {ForceModelKind::kelvin_voigt, {4.0, 5e-6, 0.0}, 2},
                                     {ForceModelKind::hertz, {1e9, 10e-9, 0.0}, 2},
                                     {ForceModelKind::dmt, {1e9, 10e-9, 1e-19, 0.3e-9, 0.0}, 4},
                                     {ForceModelKind::dmt_viscous, {1e9, 10e-9, 1e-19, 0.3e-9, 0.0, 200.0}, 4}};
  const ModalModel modal(paper_probe_spec());
  const double f1 = first_resonance_hz(modal);
  // The surface at 60 % of the free amplitude, from the free steady state: the window holds the
  // tapping as it sets in (a run-in with the reference settles, for this cantilever, in the
  // bistable regime's low-amplitude state that no longer touches).
  const double a = drive_for_free_amplitude(modal, 45e-9);
  const ModalState start = linear_steady_state(modal, a, f1, 0.0, 0.0);
  std::vector<std::unique_ptr<ForwardCase>> out;
  for (const Model& m : models) {
    std::vector<double> full = m.params;
    full[static_cast<std::size_t>(m.h_index)] = 0.6 * 45e-9;
    for (double d : {a, f1, 0.0, 0.0}) full.push_back(d);
    const int n_full = static_cast<int>(full.size());
    for (double dt : {1e-7, 5e-7, 1e-6}) {
      Window w = sine_window(1250, dt, a, f1);
      const ReferenceResult ref = reference_simulate(modal, m.model, w, full, start);
      if (std::none_of(ref.force_n.begin(), ref.force_n.end(), [](double f) { return f < 0; }))
        throw std::logic_error("work-precision case without contact: " + std::string(to_string(m.model)));
      w.deflection_m = ref.signal;
      auto set = [&](int s) {
        std::vector<double> p = full;
        p[0] *= 1.0 + 0.2 * (s - batch / 2) / batch;
        return p;
      };
      out.push_back(std::make_unique<ForwardCase>(std::string(to_string(m.model)), m.model, std::move(w), start, full,
                                                  batch, soa_of(n_full, batch, set)));
    }
  }
  return out;
}

}  // namespace tipforce::bench
