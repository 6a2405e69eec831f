// The CPU forward backend: blocks of parameter sets advanced together through the window, the
// modal updates written over the block so that they vectorise, the batch split across threads.
#include <algorithm>
#include <condition_variable>
#include <functional>
#include <mutex>
#include <thread>

#include "tipforce/assert.hpp"
#include "tipforce/detail/forward_setup.hpp"
#include "tipforce/drive.hpp"

namespace tipforce {
namespace {

using detail::LaneForce;

using detail::kMaxModes;
constexpr int kBlock = 16;  // sets advanced together; the block's state stays in L1

// Runs fn(chunk) for chunk in [0, n): chunk i on thread i % size(), the caller being thread 0.
// Every worker takes part in every run, so run() returns only when no worker still holds fn.
class ThreadPool {
 public:
  explicit ThreadPool(int threads) {
    for (int i = 1; i < threads; ++i) workers_.emplace_back([this, i] { work(i); });
  }
  ~ThreadPool() {
    {
      std::lock_guard lock(mutex_);
      stop_ = true;
    }
    wake_.notify_all();
    for (auto& w : workers_) w.join();
  }
  int size() const { return static_cast<int>(workers_.size()) + 1; }

  void run(int n, const std::function<void(int)>& fn) {
    if (n <= 1 || workers_.empty()) {
      for (int i = 0; i < n; ++i) fn(i);
      return;
    }
    {
      std::lock_guard lock(mutex_);
      job_ = &fn;
      n_jobs_ = n;
      pending_ = static_cast<int>(workers_.size());
      ++generation_;
    }
    wake_.notify_all();
    for (int i = 0; i < n; i += size()) fn(i);
    std::unique_lock lock(mutex_);
    done_.wait(lock, [&] { return pending_ == 0; });
    job_ = nullptr;
  }

 private:
  void work(int index) {
    std::uint64_t seen = 0;
    for (;;) {
      const std::function<void(int)>* job;
      int n;
      {
        std::unique_lock lock(mutex_);
        wake_.wait(lock, [&] { return stop_ || generation_ != seen; });
        if (stop_) return;
        seen = generation_;
        job = job_;
        n = n_jobs_;
      }
      for (int i = index; i < n; i += size()) (*job)(i);
      std::lock_guard lock(mutex_);
      if (--pending_ == 0) done_.notify_all();
    }
  }

  std::vector<std::thread> workers_;
  std::mutex mutex_;
  std::condition_variable wake_, done_;
  const std::function<void(int)>* job_ = nullptr;
  int n_jobs_ = 0;
  int pending_ = 0;
  std::uint64_t generation_ = 0;
  bool stop_ = false;
};

// Constants of one solve, shared by all blocks.
struct Setup {
  const ForwardProblem* pb;
  const ForwardBatch* batch;
  int n_modes, n_samples;
  int substeps;                        // coarse steps per sample
  const detail::ModeConstants* levels;  // coarse step and its refinements
  detail::ContactResolution resolution;
  bool displacement;
  const detail::SharedDrive* drive;  // null when the drive varies per set
};

// The lanes' outputs at sample n.
template <int L>
void record(const Setup& S, int s0, int nb, int n, const detail::LaneBlock<kMaxModes, L>& b, const double* sig,
            ForwardOutput& out) {
  const ForwardBatch& batch = *S.batch;
  for (int l = 0; l < nb; ++l) {
    const std::size_t idx = static_cast<std::size_t>(s0 + l) * S.n_samples + n;
    if (batch.want_signal) out.signal[idx] = sig[l];
    if (batch.want_force) {
      out.force_n[idx] = b.f[l];
      out.tip_z_m[idx] = b.z[l];
    }
  }
}

// L, the lanes advanced together, is a compile-time constant so that every lane loop is one or a
// few whole vectors with no remainder handling. The arithmetic is detail/forward_step.hpp's.
// Inlined into each instruction-set clone of solve_blocks (below), so that every clone vectorises
// the whole step for its own vector width.
#define TIPFORCE_INTO_CLONE [[gnu::always_inline]] inline

template <int L, int LD, class Source>
TIPFORCE_INTO_CLONE void solve_block(const Setup& S, int s0, int nb, const Source& src, ForwardOutput& out) {
  static_assert(L <= kBlock && L % 4 == 0);
  const int M = S.n_modes, N = S.n_samples, K = S.substeps;
  const ForwardBatch& batch = *S.batch;
  const Window& w = *S.pb->window;
  const int model = static_cast<int>(S.pb->model);
  alignas(64) detail::LaneBlock<kMaxModes, L> b;
  LaneForce lf[L];
  double y0[L], yd0[L], sig[L], cost[L];
  for (int l = 0; l < L; ++l) {
    const int s = s0 + std::min(l, nb - 1);  // pad the block with copies of its last set
    lf[l] = detail::lane_force_of_set(S.pb->model, batch, s);
    const ModalState& init = batch.initial.size() == 1 ? batch.initial[0] : batch.initial[static_cast<std::size_t>(s)];
    for (int i = 0; i < M; ++i) {
      b.q[i][l] = init.q[static_cast<std::size_t>(i)];
      b.v[i][l] = init.v[static_cast<std::size_t>(i)];
    }
    if constexpr (LD == 1) {
      y0[l] = S.drive->y_m[0];
      yd0[l] = S.drive->ydot_m_per_s[0];
    } else {
      const detail::Motion m = src.fn[l].at(w.t0_s);
      y0[l] = m.y;
      yd0[l] = m.yd;
    }
  }
  detail::start_block(S.levels[0], M, lf, S.resolution, S.levels[0].h_s, y0, yd0, b);
  const bool tracing = batch.want_signal || batch.want_force;
  detail::measured_signal(S.levels[0], M, S.displacement, b, sig);
  for (int l = 0; l < L; ++l) {
    const double r = w.deflection_m[0] - sig[l];
    cost[l] = r * r;
  }
  if (tracing) record<L>(S, s0, nb, 0, b, sig, out);
  const double h = S.levels[0].h_s;
  for (int j = 0; j < N * K; ++j) {
    detail::advance_coarse_step<kMaxModes, L, LD>(S.levels, M, model, lf, S.resolution, src, j, w.t0_s + j * h, b);
    if ((j + 1) % K != 0 || (j + 1) / K >= N) continue;
    const int n = (j + 1) / K;
    detail::measured_signal(S.levels[0], M, S.displacement, b, sig);
    const double meas = w.deflection_m[static_cast<std::size_t>(n)];
    for (int l = 0; l < L; ++l) {
      const double r = meas - sig[l];
      cost[l] += r * r;
    }
    if (tracing) record<L>(S, s0, nb, n, b, sig, out);
  }
  for (int l = 0; l < nb; ++l) {
    out.cost[static_cast<std::size_t>(s0 + l)] = cost[l];
    if (batch.want_end_state) {
      ModalState& e = out.end_state[static_cast<std::size_t>(s0 + l)];
      e.q.assign(static_cast<std::size_t>(M), 0.0);
      e.v.assign(static_cast<std::size_t>(M), 0.0);
      for (int i = 0; i < M; ++i) {
        e.q[static_cast<std::size_t>(i)] = b.q[i][l];
        e.v[static_cast<std::size_t>(i)] = b.v[i][l];
      }
    }
  }
}

template <int L>
TIPFORCE_INTO_CLONE void solve_block_any_drive(const Setup& S, int s0, int nb, ForwardOutput& out) {
  if (S.drive) {
    detail::SharedDriveSource src;
    src.y_m = S.drive->y_m.data();
    src.yd_m = S.drive->ydot_m_per_s.data();
    src.dq = S.drive->dq.data();
    src.dv = S.drive->dv.data();
    src.dq_stride = S.n_modes;
    src.fn = S.drive->fn;
    solve_block<L, 1>(S, s0, nb, src, out);
    return;
  }
  detail::PerLaneDriveSource<L> src;
  const ForwardBatch& batch = *S.batch;
  for (int l = 0; l < L; ++l) {
    const int s = s0 + std::min(l, nb - 1);
    const auto dp = FullParams(ParameterLayout(S.pb->model), batch.params, batch.n_sets, s).drive();
    src.fn[l] = detail::analytic_drive(*S.pb->window, dp.data());
  }
  solve_block<L, L>(S, s0, nb, src, out);
}

TIPFORCE_INTO_CLONE void solve_blocks_body(const Setup& S, int s0, int nb, ForwardOutput& out) {
  if (nb <= 4) solve_block_any_drive<4>(S, s0, nb, out);
  else if (nb <= 8) solve_block_any_drive<8>(S, s0, nb, out);
  else solve_block_any_drive<16>(S, s0, nb, out);
}

// One binary for every x86-64: the library is built for the baseline instruction set, and the
// forward step is cloned for AVX2+FMA (x86-64-v3) and AVX-512 (x86-64-v4), the clone chosen when
// the program loads (GCC's function multi-versioning, an ifunc). Everything the clones call that is
// not inlined stays baseline code, so no clone's instructions leak into code the others run;
// flatten inlines the whole step into each clone (the compiler would otherwise keep the large
// step functions out of line, in baseline code).
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
[[gnu::target_clones("arch=x86-64-v4", "arch=x86-64-v3", "default")]]
#endif
[[gnu::flatten]] void solve_blocks_dispatched(const Setup& S, int s0, int nb, ForwardOutput& out) {
  solve_blocks_body(S, s0, nb, out);
}

// The baseline build of the same step (tests compare the clones with it).
[[gnu::flatten]] void solve_blocks_baseline(const Setup& S, int s0, int nb, ForwardOutput& out) { solve_blocks_body(S, s0, nb, out); }

class CpuBackend final : public ForwardBackend {
 public:
  CpuBackend(int threads, CpuIsa isa) : pool_(threads), isa_(isa) {}
  CpuBackend(const CpuBackend&) = delete;
  CpuBackend& operator=(const CpuBackend&) = delete;
  std::string description() const override { return "cpu: " + std::to_string(pool_.size()) + " threads"; }

  void solve(const ForwardProblem& pb, const ForwardBatch& batch, ForwardOutput& out) override {
    detail::check_forward_batch(pb, batch, kMaxModes);
    const ModalModel& modal = *pb.modal;
    const Window& w = *pb.window;
    const int M = modal.n_modes(), N = w.n_samples(), S = batch.n_sets;

    Setup setup{};
    setup.pb = &pb;
    setup.batch = &batch;
    setup.n_modes = M;
    setup.n_samples = N;
    setup.substeps = pb.substeps;
    const StepCoefficients& st = *pb.step;
    setup.levels = levels_.get(modal, st);
    setup.resolution = detail::contact_resolution(modal, pb);
    setup.displacement = modal.sensor() == Sensor::displacement;
    if (!batch.drive_varies || w.drive.kind == DriveKind::sampled) {
      // An inversion solves many batches of one window: evaluate its drive once.
      DriveKey key{&w, &st, pb.substeps, N, w.t0_s, w.drive.kind, {}};
      const auto dp = FullParams(ParameterLayout(pb.model), batch.params, S, 0).drive();
      std::copy(dp.begin(), dp.end(), key.params);
      if (!(key == drive_key_) || w.drive.kind == DriveKind::sampled) {
        detail::make_shared_drive(modal, st, w, key.params, pb.substeps, drive_);
        drive_key_ = key;
      }
      setup.drive = &drive_;
    }

    out.cost.assign(static_cast<std::size_t>(S), 0.0);
    const std::size_t trace = static_cast<std::size_t>(S) * N;
    if (batch.want_signal) out.signal.assign(trace, 0.0);
    if (batch.want_force) {
      out.force_n.assign(trace, 0.0);
      out.tip_z_m.assign(trace, 0.0);
    }
    if (batch.want_end_state) out.end_state.assign(static_cast<std::size_t>(S), ModalState{});
    // Blocks of at most kBlock sets, small enough that every thread gets one when the batch is small.
    const int per_thread = (S + pool_.size() - 1) / pool_.size();
    const int width = std::clamp((per_thread + 3) / 4 * 4, 4, kBlock);
    const int blocks = (S + width - 1) / width;
    pool_.run(blocks, [&](int b) {
      const int s0 = b * width, nb = std::min(width, S - s0);
      if (isa_ == CpuIsa::baseline)
        solve_blocks_baseline(setup, s0, nb, out);
      else
        solve_blocks_dispatched(setup, s0, nb, out);
    });
  }

 private:
  struct DriveKey {
    const Window* window = nullptr;
    const StepCoefficients* step = nullptr;
    int substeps = 0, n = 0;
    double t0 = 0;
    DriveKind kind = DriveKind::sine;
    double params[4] = {};
    bool operator==(const DriveKey& o) const {
      return window == o.window && step == o.step && substeps == o.substeps && n == o.n && t0 == o.t0 &&
             kind == o.kind && std::equal(params, params + 4, o.params);
    }
  };
  ThreadPool pool_;
  CpuIsa isa_;
  detail::StepLevels levels_;
  DriveKey drive_key_;
  detail::SharedDrive drive_;
};

}  // namespace

std::unique_ptr<ForwardBackend> make_cpu_backend(int threads, CpuIsa isa) {
  if (threads <= 0) threads = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  return std::make_unique<CpuBackend>(threads, isa);
}

int default_substeps(ForceModelKind) { return 1; }

double default_contact_rad_per_substep(ForceModelKind model) {
  switch (model) {
    case ForceModelKind::spring: return 0.1;
    case ForceModelKind::kelvin_voigt: return 0.04;
    case ForceModelKind::hertz: return 0.02;
    case ForceModelKind::dmt: return 0.003;
    case ForceModelKind::dmt_viscous: return 0.01;
    default: return 0.01;
  }
}

bool default_extrapolate_contact(ForceModelKind model) { return model != ForceModelKind::dmt; }

ForwardOutput simulate_one(ForwardBackend& backend, const ModalModel& modal, ForceModelKind model, const Window& window,
                           std::span<const double> full_params, const ModalState& initial, int substeps) {
  if (substeps <= 0) substeps = default_substeps(model);
  const StepCoefficients step = make_step_coefficients(modal, window.sample_period_s / substeps);
  ForwardProblem pb{&modal, &step, model, &window, substeps};
  ForwardBatch batch;
  batch.n_sets = 1;
  batch.params = full_params;
  batch.initial = std::span<const ModalState>(&initial, 1);
  batch.want_signal = batch.want_force = batch.want_end_state = true;
  ForwardOutput out;
  backend.solve(pb, batch, out);
  return out;
}

}  // namespace tipforce
