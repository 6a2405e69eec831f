// The CPU forward backend: blocks of parameter sets advanced together through the window (the
// lane loops vectorise across sets), the batch split across threads, each block solved by the
// build of cpu_step.hpp for the best instruction set this CPU has.
#include <algorithm>
#include <array>
#include <cmath>
#include <numeric>
#include <thread>

#include "cpu_step.hpp"
#include "thread_pool.hpp"
#include "tipforce/assert.hpp"
#include "tipforce/detail/forward_setup.hpp"
#include "tipforce/drive.hpp"

namespace tipforce {
namespace {

using detail::LaneForce;

using cpu::kLanes;

// The best build of the block solve this CPU runs (cpu_step.hpp).
cpu::Isa best_isa() {
#if defined(TIPFORCE_CPU_CLONES)
  __builtin_cpu_init();
  if (__builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512dq") && __builtin_cpu_supports("avx512bw") &&
      __builtin_cpu_supports("avx512vl") && __builtin_cpu_supports("avx512cd"))
    return cpu::Isa::x86_64_v4;
  if (__builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma") && __builtin_cpu_supports("bmi2"))
    return cpu::Isa::x86_64_v3;
#endif
  return cpu::Isa::baseline;
}

void solve_block_for(cpu::Isa isa, cpu::BlockJob& job) {
#if defined(TIPFORCE_CPU_CLONES)
  if (isa == cpu::Isa::x86_64_v4) return cpu::solve_block_x86_64_v4(job);
  if (isa == cpu::Isa::x86_64_v3) return cpu::solve_block_x86_64_v3(job);
#endif
  (void)isa;
  cpu::solve_block_baseline(job);
}

// The substep levels a set's contact steps take, as one sort key (the crossing level, then the
// contact level): a block takes each contact step at its finest lane's level, so sets of one level
// belong together. A Hertzian law's level follows the penetration its path reaches; its contact
// stiffness at 1 nm of it stands in.
double substep_level_key(const detail::LaneForce& lf, const detail::ContactResolution& res, double coarse_h_s) {
  double k_n_per_m = 0, c_ns_per_m = 0;
  switch (lf.model) {
    case detail::kSpring: k_n_per_m = lf.k; break;
    case detail::kKelvinVoigt:
      k_n_per_m = lf.k;
      c_ns_per_m = lf.c;
      break;
    case detail::kHertz:
    case detail::kDmt:
    case detail::kDmtViscous: k_n_per_m = 1.5 * lf.big_k * std::sqrt(1e-9); break;
    default: return 0;
  }
  if (!(k_n_per_m >= 0) || !(c_ns_per_m >= 0)) return HUGE_VAL;  // NaN: last
  const auto level = [&](double rad_per_substep) {
    return detail::level_for(k_n_per_m, c_ns_per_m, 0.0, coarse_h_s, res, rad_per_substep);
  };
  // As start_block sets them: crossings never coarser than the contact around them.
  const int contact = level(res.rad_per_substep), crossing = std::max(level(res.crossing_rad_per_substep), contact);
  return detail::kSubstepLevels * crossing + contact;
}

}  // namespace

void cpu::lag_products(const double* r, int n, int lags, double* out, bool best) {
  static const cpu::Isa isa = best_isa();  // the machine's, fixed for the process
  const cpu::Isa use = best ? isa : cpu::Isa::baseline;
#if defined(TIPFORCE_CPU_CLONES)
  if (use == cpu::Isa::x86_64_v4) return cpu::lag_products_x86_64_v4(r, n, lags, out);
  if (use == cpu::Isa::x86_64_v3) return cpu::lag_products_x86_64_v3(r, n, lags, out);
#endif
  (void)use;
  cpu::lag_products_baseline(r, n, lags, out);
}

namespace {

class CpuBackend final : public ForwardBackend {
 public:
  CpuBackend(int threads, CpuIsa isa) : pool_(threads), isa_(isa == CpuIsa::baseline ? cpu::Isa::baseline : best_isa()) {}
  CpuBackend(const CpuBackend&) = delete;
  CpuBackend& operator=(const CpuBackend&) = delete;
  std::string description() const override { return "cpu: " + std::to_string(pool_.size()) + " threads"; }

  void solve(const ForwardProblem& pb, const ForwardBatch& batch, ForwardOutput& out) override {
    detail::check_forward_batch(pb, batch, detail::kMaxModes);
    const ModalModel& modal = *pb.modal;
    const Window& w = *pb.window;
    const int M = modal.n_modes(), N = w.n_samples(), S = batch.n_sets;
    const StepCoefficients& st = *pb.step;
    const int P = M <= 8 ? 8 : 32;

    cpu::BlockJob proto;
    proto.model = static_cast<int>(pb.model);
    proto.n_samples = N;
    proto.substeps = pb.substeps;
    const bool shared_drive = !batch.drive_varies || w.drive.kind == DriveKind::sampled;
    proto.samples_per_step = detail::samples_per_step(pb, batch);
    proto.t0_s = w.t0_s;
    proto.displacement = modal.sensor() == Sensor::displacement;
    proto.deflection = w.deflection_m.data();
    proto.resolution = detail::contact_resolution(modal, pb);
    // A new sample period's levels on every core: 11 ms of a stream's first window, serially
    // (8 modes at 1 MHz), which the windows behind it waited out.
    const auto on_pool = [this](int n, const std::function<void(int)>& fn) { pool_.run(n, fn); };
    if (P == 8) proto.levels8 = levels8_.get(modal, st, proto.samples_per_step, on_pool);
    else proto.levels32 = levels32_.get(modal, st, proto.samples_per_step, on_pool);
    proto.drive_kind = static_cast<int>(w.drive.kind);
    if (shared_drive) {
      // An inversion solves many batches of one window: evaluate its drive once.
      const auto dp = FullParams(ParameterLayout(pb.model), batch.params, S, 0).drive();
      key_scratch_.assign(modal, st, w, dp.data(), pb.substeps, proto.samples_per_step, P);
      if (!drive_valid_ || !(key_scratch_ == drive_key_)) {
        drive_valid_ = false;
        if (P == 8) detail::make_shared_drive<8>(proto.levels8[0], w, dp.data(), pb.substeps, proto.samples_per_step, drive_);
        else detail::make_shared_drive<32>(proto.levels32[0], w, dp.data(), pb.substeps, proto.samples_per_step, drive_);
        drive_key_.swap(key_scratch_);
        drive_valid_ = true;
      }
      if (drive_.held) proto.held = &drive_.hold;
      else proto.sine = &drive_.sine;
    }

    out.cost.assign(static_cast<std::size_t>(S), 0.0);
    const std::size_t trace = static_cast<std::size_t>(S) * N;
    if (batch.want_signal) out.signal.assign(trace, 0.0);
    if (batch.want_force) {
      out.force_n.assign(trace, 0.0);
      out.tip_z_m.assign(trace, 0.0);
    }
    if (batch.want_end_state) out.end_state.assign(static_cast<std::size_t>(S), ModalState{});
    // The blocks: from the batch alone, so that a set's arithmetic (and so its result) does not
    // depend on how many threads share the batch.
    const int per_block = sets_per_block(batch);
    proto.width = block_width(per_block);
    const int blocks = (S + per_block - 1) / per_block;
    order_sets(pb.model, batch, per_block, proto.resolution, P == 8 ? proto.levels8[0].h_s : proto.levels32[0].h_s);
    pool_.run(blocks, [&](int blk) {
      const int s0 = blk * per_block, nb = std::min(per_block, S - s0);
      const int* sets = order_.data() + s0;
      cpu::BlockJob job = proto;
      prepare(job, pb, batch, sets, nb, M, N, out);
      solve_block_for(isa_, job);
      finish(job, batch, sets, nb, M, out);
    });
  }

 private:
  // Sets per block: the caller's grouping (ForwardBatch::sets_per_block), else half the batch (two
  // blocks, for two cores, when it has at most 2 x kLanes sets), at most kLanes. Not from the
  // thread count: see above.
  static int sets_per_block(const ForwardBatch& batch) {
    if (batch.sets_per_block > 0) return std::min(batch.sets_per_block, kLanes);
    return std::clamp((batch.n_sets + 1) / 2, 1, kLanes);
  }
  // The batch's sets in block order (order_[b x per_block ...] share block b). Where the grouping is
  // the backend's, sets are grouped by their contact's substep levels, then their surface, then
  // their stiffness: a block takes every contact step at its finest lane's level and every lane
  // through any lane's crossing substeps, so a stiff lane or a contact that begins at another
  // instant multiplies its work (lib/src/DESIGN.md, "Blocks grouped by level and surface"). A
  // caller's grouping (sets_per_block) is kept as given: its finite differences stay in one block.
  // The order depends on the batch's sets alone, not on their order in it.
  void order_sets(ForceModelKind model, const ForwardBatch& batch, int per_block, const detail::ContactResolution& res,
                  double coarse_h_s) {
    const int S = batch.n_sets;
    order_.resize(static_cast<std::size_t>(S));
    std::iota(order_.begin(), order_.end(), 0);
    if (batch.sets_per_block > 0 || S <= per_block) return;
    keys_.resize(static_cast<std::size_t>(S));
    // NaN last, so that the comparison stays a strict weak order.
    const auto key = [](double x) { return std::isnan(x) ? HUGE_VAL : x; };
    for (int s = 0; s < S; ++s) {
      const detail::LaneForce lf = detail::lane_force_of_set(model, batch, s);
      keys_[static_cast<std::size_t>(s)] = {substep_level_key(lf, res, coarse_h_s), key(lf.h), key(lf.k),
                                            key(lf.big_k)};
    }
    // Ties by the rest of the set (its other parameters, drive included, then its own initial
    // state), so that sets differing only there take the same blocks in any order of the batch; the
    // index last, between copies of one set (a total order: no stable sort's buffer per batch).
    const std::size_t n_full = batch.params.size() / static_cast<std::size_t>(S);
    const auto less = [&](double x, double y) { return key(x) < key(y); };
    const auto rest_precedes = [&](int a, int b) {
      for (std::size_t k = 0; k < n_full; ++k) {
        const double x = batch.params[k * S + a], y = batch.params[k * S + b];
        if (less(x, y)) return true;
        if (less(y, x)) return false;
      }
      if (batch.initial.size() > 1) {
        const ModalState& ia = batch.initial[static_cast<std::size_t>(a)];
        const ModalState& ib = batch.initial[static_cast<std::size_t>(b)];
        for (const auto part : {&ModalState::q, &ModalState::v}) {
          if (std::ranges::lexicographical_compare(ia.*part, ib.*part, less)) return true;
          if (std::ranges::lexicographical_compare(ib.*part, ia.*part, less)) return false;
        }
      }
      return a < b;
    };
    std::sort(order_.begin(), order_.end(), [&](int a, int b) {
      const auto& ka = keys_[static_cast<std::size_t>(a)];
      const auto& kb = keys_[static_cast<std::size_t>(b)];
      return ka != kb ? ka < kb : rest_precedes(a, b);
    });
  }

  // The narrowest block width that holds them.
  static int block_width(int per_block) {
    for (int w : cpu::kWidths)
      if (w >= per_block) return w;
    return kLanes;
  }

  // The block's lanes (sets[0 .. nb), padded with copies of the last), drives and initial state,
  // and where its traces go.
  static void prepare(cpu::BlockJob& job, const ForwardProblem& pb, const ForwardBatch& batch, const int* sets, int nb,
                      int M, int N, ForwardOutput& out) {
    const ParameterLayout layout(pb.model);
    for (int l = 0; l < job.width; ++l) {
      const int s = sets[std::min(l, nb - 1)];
      job.lanes[l] = detail::lane_force_of_set(pb.model, batch, s);
      if (!job.sine && !job.held) {
        const auto d = FullParams(layout, batch.params, batch.n_sets, s).drive();
        std::copy(d.begin(), d.end(), job.drive_params[l]);
      }
      const ModalState& init = batch.initial.size() == 1 ? batch.initial[0] : batch.initial[static_cast<std::size_t>(s)];
      for (int i = 0; i < M; ++i) {
        job.q[i][l] = init.q[static_cast<std::size_t>(i)];
        job.v[i][l] = init.v[static_cast<std::size_t>(i)];
      }
    }
    job.n_lanes = nb;
    job.traces = batch.want_signal || batch.want_force;
    for (int l = 0; l < nb; ++l) {
      const std::size_t row = static_cast<std::size_t>(sets[l]) * N;
      job.signal[l] = batch.want_signal ? out.signal.data() + row : nullptr;
      job.force[l] = batch.want_force ? out.force_n.data() + row : nullptr;
      job.tip_z[l] = batch.want_force ? out.tip_z_m.data() + row : nullptr;
    }
  }
  static void finish(const cpu::BlockJob& job, const ForwardBatch& batch, const int* sets, int nb, int M,
                     ForwardOutput& out) {
    for (int l = 0; l < nb; ++l) {
      const std::size_t s = static_cast<std::size_t>(sets[l]);
      out.cost[s] = job.cost[l];
      if (!batch.want_end_state) continue;
      ModalState& e = out.end_state[s];
      e.q.resize(static_cast<std::size_t>(M));
      e.v.resize(static_cast<std::size_t>(M));
      for (int i = 0; i < M; ++i) {
        e.q[static_cast<std::size_t>(i)] = job.q[i][l];
        e.v[static_cast<std::size_t>(i)] = job.v[i][l];
      }
    }
  }

  cpu::ThreadPool pool_;
  cpu::Isa isa_;
  detail::StepLevels<8> levels8_;
  detail::StepLevels<32> levels32_;
  detail::SharedDriveKey drive_key_, key_scratch_;
  bool drive_valid_ = false;
  detail::SharedDrive drive_;
  std::vector<int> order_;                   // order_sets
  std::vector<std::array<double, 4>> keys_;  // its sort keys, kept for their allocation
};

}  // namespace

std::unique_ptr<ForwardBackend> make_cpu_backend(int threads, CpuIsa isa) {
  if (threads <= 0) threads = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  return std::make_unique<CpuBackend>(threads, isa);
}

int default_substeps(ForceModelKind) { return 1; }

double default_contact_rad_per_substep(ForceModelKind model) {
  switch (model) {
    case ForceModelKind::spring: return 0.35;
    case ForceModelKind::kelvin_voigt: return 0.1;
    case ForceModelKind::hertz: return 0.25;
    case ForceModelKind::dmt: return 0.1;
    case ForceModelKind::dmt_viscous: return 0.15;
    default: return 0.35;
  }
}

double default_crossing_rad_per_substep(ForceModelKind model) {
  switch (model) {
    case ForceModelKind::spring: return 0.0875;
    case ForceModelKind::kelvin_voigt: return 0.0125;
    case ForceModelKind::hertz: return 0.0625;
    case ForceModelKind::dmt: return 0.025;
    case ForceModelKind::dmt_viscous: return 0.019;
    default: return 0.0875;
  }
}

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
