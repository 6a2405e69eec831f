#pragma once
// The forward-solver workloads that tipforce's speed figures are quoted for, in one place:
// `tipforce bench` (its JSON and the README's tables) and the Google Benchmark suite
// (tipforce_benchmarks) time the same batches, so their figures can be set side by side.
#include <memory>
#include <string>
#include <vector>

#include "tipforce/forward.hpp"

namespace tipforce::bench {

// One window and a batch of parameter sets over it, ready for ForwardBackend::solve. Holds what
// the problem points to, so it stays where it was made (no copy, no move).
class ForwardCase {
 public:
  ForwardCase(std::string name, ForceModelKind model, Window window, ModalState start, std::vector<double> central,
              int batch, std::vector<double> params_soa);
  ForwardCase(const ForwardCase&) = delete;
  ForwardCase& operator=(const ForwardCase&) = delete;

  const std::string& name() const { return name_; }
  ForceModelKind model() const { return model_; }
  const ModalModel& modal() const { return modal_; }
  const Window& window() const { return window_; }
  const ModalState& start() const { return start_; }
  // The case's central parameter set (model parameters, then drive): the one checked against the
  // reference integrator.
  const std::vector<double>& central() const { return central_; }
  int batch() const { return batch_; }
  ForwardProblem problem() const {
    ForwardProblem pb{&modal_, &step_, model_, &window_, 1};
    pb.contact_rad_per_substep = contact_rad_per_substep_;
    pb.crossing_rad_per_substep = crossing_rad_per_substep_;
    return pb;
  }
  // Solve at this contact and crossing resolution (ForwardProblem's; 0: the model's defaults).
  void set_resolution(double contact_rad_per_substep, double crossing_rad_per_substep) {
    contact_rad_per_substep_ = contact_rad_per_substep;
    crossing_rad_per_substep_ = crossing_rad_per_substep;
  }
  ForwardBatch forward_batch() const;
  // Relative L2 error of the fast solver's central set against the reference integrator.
  double error_against_reference(ForwardBackend& backend) const;

 private:
  std::string name_;
  ModalModel modal_;
  ForceModelKind model_;
  Window window_;
  ModalState start_;
  StepCoefficients step_;
  std::vector<double> central_;
  int batch_;
  std::vector<double> params_soa_;
  double contact_rad_per_substep_ = 0, crossing_rad_per_substep_ = 0;
};

// The CPU's model name from /proc/cpuinfo, for the figures' header (machines here are Intel
// AVX-512 or AMD AVX2, about 2x apart); "unknown CPU" where it cannot be read.
std::string cpu_model_name();

// The drive amplitude (m) at the first resonance that gives the paper's cantilever this free tip
// amplitude.
double drive_for_free_amplitude(const ModalModel& modal, double free_amplitude_m);

// Firm spring tapping: k 2-6 N/m across the batch, surface at 25 nm, 2 nm drive at 25.6 kHz
// (about 220 nm of free amplitude, the tip on the surface most of each period), from the free
// steady state. At 1000 samples and 1e-7 s: the issue's "core definition" of a forward solve.
std::unique_ptr<ForwardCase> firm_tapping(int samples, double sample_period_s, int batch);

// Issue 8's own setup: the paper's cantilever driven at resonance to 45 nm of free amplitude,
// spring contact with k 1-4 N/m across the batch at h 20 nm, from the free steady state; its
// central set is k 2.5 N/m.
std::unique_ptr<ForwardCase> issue8_tapping(int samples, double sample_period_s, int batch, double k_n_per_m = 2.5);

// The batches a cold start solves, at issue 8's tapping (45 nm free amplitude at f1, from the free
// steady state), spring, at the search's resolution (InversionOptions' search_contact_rad_per_substep
// and search_crossing_rad_per_substep): the physics grid over the window's head (grid_periods
// periods of mode 1; the default cold_physics_grid cells of k, evenly in its logarithm over 0.1-20
// N/m, times the default indentation fractions below a 45 nm reach: 120 sets), and a search's
// scattered candidates over the whole window (k 0.5-20 N/m, evenly in its logarithm, and h 10-40 nm
// at random, fixed seed). Their cost depends on which sets share a block (lib/src/DESIGN.md).
std::unique_ptr<ForwardCase> cold_grid(double sample_period_s);
std::unique_ptr<ForwardCase> scattered_search(int samples, double sample_period_s, int batch);

// The work-precision table's cases: per force model and sample period (1e-7, 5e-7, 1e-6 s), a
// 1250-sample window of tapping at 45 nm of free amplitude with the surface at 60 % of it, from
// the free steady state; the first parameter varies +-10 % across the batch. The window's
// deflection is the reference integrator's signal of the central set, so a solve's cost is a
// fit's.
std::vector<std::unique_ptr<ForwardCase>> work_precision_cases(int batch);

}  // namespace tipforce::bench
