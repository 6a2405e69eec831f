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

using detail::ContactResult;
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
  int n_modes, n_samples, n_model_params;
  int substeps;
  double dt;  // solver step: sample period / substeps
  detail::ModeConstants k;
  detail::TipStepResponse tip;
  bool displacement;  // sensor reads phi(L) q: the signal is z - y
  const detail::SharedDrive* drive;  // null when the drive varies per set
};

// Spring and Kelvin-Voigt steps that stay on their branch, for all lanes at once without branches
// (the compiler vectorises this); lanes whose branch changes are flagged for the exact scalar step.
template <int kModel, int L>
void regular_contact_lanes(const LaneForce* lf, const detail::TipStepResponse& tip, const double* zh,
                           const double* zdh, const bool* in, double* f, double* z, double* zd, double* al, double* be,
                           bool* cross) {
#pragma GCC ivdep
  for (int l = 0; l < L; ++l) {
    const double k = lf[l].k, h = lf[l].h, c = kModel == detail::kKelvinVoigt ? lf[l].c : 0.0;
    double fin = (-k * (zh[l] - h) - c * zdh[l]) / (1.0 + k * tip.z_end + c * tip.v_end);
    if (kModel == detail::kKelvinVoigt) fin = fin < 0.0 ? fin : 0.0;
    const double f1 = in[l] ? fin : 0.0;
    const double z1 = zh[l] + tip.z_end * f1, zd1 = zdh[l] + tip.v_end * f1;
    const double delta = z1 - h;
    const double s1 = kModel == detail::kKelvinVoigt ? std::min(k * delta, k * delta + c * zd1) : delta;
    cross[l] = (s1 > 0) != in[l];
    f[l] = f1;
    z[l] = z1;
    zd[l] = zd1;
    al[l] = f1;
    be[l] = 0.0;
  }
}

// L, the lanes advanced together, is a compile-time constant so that every lane loop is one or a
// few whole vectors with no remainder handling.
template <int L>
void solve_block(const Setup& S, int s0, int nb, ForwardOutput& out) {
  static_assert(L <= kBlock && L % 4 == 0);
  const int M = S.n_modes, N = S.n_samples;
  const ForwardBatch& batch = *S.batch;
  const Window& w = *S.pb->window;
  const StepCoefficients& st = *S.pb->step;
  alignas(64) double q[kMaxModes][kBlock], v[kMaxModes][kBlock];
  alignas(64) double f[kBlock], z[kBlock], zd[kBlock], zh[kBlock], zdh[kBlock], al[kBlock], be[kBlock], cost[kBlock];
  alignas(64) double y1[kBlock], yd1[kBlock];
  alignas(64) double z0[kBlock], zd0[kBlock], f0[kBlock];
  bool in[kBlock], in0[kBlock], cross[kBlock];
  LaneForce lf[kBlock];
  // Per-set drive, when it varies: parameters and the acceleration at the step start.
  double dpar[kBlock][4], acc0[kBlock];

  for (int l = 0; l < L; ++l) {
    const int s = s0 + std::min(l, nb - 1);  // pad the block with copies of its last set
    lf[l] = detail::lane_force_of_set(S.pb->model, batch, s);
    const ModalState& init = batch.initial.size() == 1 ? batch.initial[0] : batch.initial[static_cast<std::size_t>(s)];
    for (int i = 0; i < M; ++i) {
      q[i][l] = init.q[static_cast<std::size_t>(i)];
      v[i][l] = init.v[static_cast<std::size_t>(i)];
    }
    for (int k = 0; k < 4; ++k)
      dpar[l][k] = batch.params[static_cast<std::size_t>(S.n_model_params + k) * batch.n_sets + s];
    double y0, yd0;
    if (S.drive) {
      y0 = S.drive->y_m[0];
      yd0 = S.drive->ydot_m_per_s[0];
    } else {
      const BaseMotion b = base_motion(w.drive.kind, dpar[l][0], dpar[l][1], dpar[l][2], dpar[l][3], w.t0_s);
      y0 = b.y_m;
      yd0 = b.ydot_m_per_s;
      acc0[l] = b.yddot_m_per_s2;
    }
    double u = 0, ud = 0, sig = 0;
    for (int i = 0; i < M; ++i) {
      u += S.k.phi[i] * q[i][l];
      ud += S.k.phi[i] * v[i][l];
      sig += S.k.gain[i] * q[i][l];
    }
    z[l] = y0 + u;
    zd[l] = yd0 + ud;
    in[l] = detail::switching(lf[l], z[l], zd[l]) > 0;
    f[l] = detail::branch_force(lf[l], in[l], z[l], zd[l]);
    const double r = w.deflection_m[0] - sig;
    cost[l] = r * r;
  }
  auto record = [&](int n) {
    for (int l = 0; l < nb; ++l) {
      const std::size_t idx = static_cast<std::size_t>(s0 + l) * N + n;
      if (batch.want_signal) {
        double sig = 0;
        for (int i = 0; i < M; ++i) sig += S.k.gain[i] * q[i][l];
        out.signal[idx] = sig;
      }
      if (batch.want_force) {
        out.force_n[idx] = f[l];
        out.tip_z_m[idx] = z[l];
      }
    }
  };
  if (batch.want_signal || batch.want_force) record(0);
  const bool contact = S.pb->model != ForceModelKind::none;
  const int K = S.substeps;

  for (int n = 0; n < N * K; ++n) {
    // Drive over the step [t_n, t_n+1].
    double dq_s[kMaxModes], dv_s[kMaxModes];
    if (S.drive) {
      for (int i = 0; i < M; ++i) {
        dq_s[i] = S.drive->dq[static_cast<std::size_t>(n) * M + i];
        dv_s[i] = S.drive->dv[static_cast<std::size_t>(n) * M + i];
      }
      for (int l = 0; l < L; ++l) {
        y1[l] = S.drive->y_m[static_cast<std::size_t>(n) + 1];
        yd1[l] = S.drive->ydot_m_per_s[static_cast<std::size_t>(n) + 1];
      }
    }
    alignas(64) double dq_l[kMaxModes][kBlock], dv_l[kMaxModes][kBlock];
    if (!S.drive) {
      const double t = w.t0_s + n * S.dt;
      for (int l = 0; l < L; ++l) {
        const double* p = dpar[l];
        const double am = base_motion(w.drive.kind, p[0], p[1], p[2], p[3], t + 0.5 * S.dt).yddot_m_per_s2;
        const BaseMotion b1 = base_motion(w.drive.kind, p[0], p[1], p[2], p[3], t + S.dt);
        for (int i = 0; i < M; ++i) detail::drive_increment(st, i, S.k.gamma[i], acc0[l], am, b1.yddot_m_per_s2, dq_l[i][l], dv_l[i][l]);
        acc0[l] = b1.yddot_m_per_s2;
        y1[l] = b1.y_m;
        yd1[l] = b1.ydot_m_per_s;
      }
    }
    for (int l = 0; l < L; ++l) {
      zh[l] = y1[l];
      zdh[l] = yd1[l];
    }
    // Exact linear update with the force held at its step-start value.
    for (int i = 0; i < M; ++i) {
      const double a00 = S.k.a00[i], a01 = S.k.a01[i], a10 = S.k.a10[i], a11 = S.k.a11[i];
      const double csq = S.k.cs_q[i], csv = S.k.cs_v[i], ph = S.k.phi[i];
      if (S.drive) {
        const double dq = dq_s[i], dv = dv_s[i];
#pragma GCC ivdep
        for (int l = 0; l < L; ++l) {
          const double qn = a00 * q[i][l] + a01 * v[i][l] + csq * f[l] + dq;
          const double vn = a10 * q[i][l] + a11 * v[i][l] + csv * f[l] + dv;
          q[i][l] = qn;
          v[i][l] = vn;
          zh[l] += ph * qn;
          zdh[l] += ph * vn;
        }
      } else {
#pragma GCC ivdep
        for (int l = 0; l < L; ++l) {
          const double qn = a00 * q[i][l] + a01 * v[i][l] + csq * f[l] + dq_l[i][l];
          const double vn = a10 * q[i][l] + a11 * v[i][l] + csv * f[l] + dv_l[i][l];
          q[i][l] = qn;
          v[i][l] = vn;
          zh[l] += ph * qn;
          zdh[l] += ph * vn;
        }
      }
    }
    if (contact) {
      // Step-end force, solved implicitly; then add the hold's correction to every mode.
      auto exact = [&](int l, double zn, double zdn, double fn, bool inn) {
        const ContactResult r = detail::contact_step(lf[l], S.tip, zh[l], zdh[l], zn, zdn, fn, inn);
        f[l] = r.f;
        in[l] = r.in;
        al[l] = r.alpha;
        be[l] = r.beta;
        z[l] = zh[l] + S.tip.z_end * r.alpha + S.tip.z_start * r.beta;
        zd[l] = zdh[l] + S.tip.v_end * r.alpha + S.tip.v_start * r.beta;
      };
      if (S.pb->model == ForceModelKind::spring || S.pb->model == ForceModelKind::kelvin_voigt) {
        for (int l = 0; l < L; ++l) {
          z0[l] = z[l];
          zd0[l] = zd[l];
          f0[l] = f[l];
          in0[l] = in[l];
        }
        if (S.pb->model == ForceModelKind::spring)
          regular_contact_lanes<detail::kSpring, L>(lf, S.tip, zh, zdh, in, f, z, zd, al, be, cross);
        else
          regular_contact_lanes<detail::kKelvinVoigt, L>(lf, S.tip, zh, zdh, in, f, z, zd, al, be, cross);
        for (int l = 0; l < L; ++l)
          if (cross[l]) exact(l, z0[l], zd0[l], f0[l], in0[l]);
      } else {
        for (int l = 0; l < L; ++l) exact(l, z[l], zd[l], f[l], in[l]);
      }
      // In free flight every hold is zero: most steps need no correction at all.
      bool any = false;
      for (int l = 0; l < L; ++l) any |= (al[l] != 0.0) | (be[l] != 0.0);
      for (int i = 0; any && i < M; ++i) {
        const double ceq = S.k.ce_q[i], cev = S.k.ce_v[i], csq = S.k.cs_q[i], csv = S.k.cs_v[i];
#pragma GCC ivdep
        for (int l = 0; l < L; ++l) {
          q[i][l] += ceq * al[l] + csq * be[l];
          v[i][l] += cev * al[l] + csv * be[l];
        }
      }
    } else {
      for (int l = 0; l < L; ++l) {
        z[l] = zh[l];
        zd[l] = zdh[l];
      }
    }
    if ((n + 1) % K == 0 && (n + 1) / K < N) {
      const int sample = (n + 1) / K;
      alignas(64) double sig[kBlock];
      if (S.displacement) {
        // The measured tip displacement is the tip's position relative to the base.
        for (int l = 0; l < L; ++l) sig[l] = z[l] - y1[l];
      } else {
        for (int l = 0; l < L; ++l) sig[l] = 0.0;
        for (int i = 0; i < M; ++i) {
          const double g = S.k.gain[i];
#pragma GCC ivdep
          for (int l = 0; l < L; ++l) sig[l] += g * q[i][l];
        }
      }
      const double meas = w.deflection_m[static_cast<std::size_t>(sample)];
      for (int l = 0; l < L; ++l) {
        const double r = meas - sig[l];
        cost[l] += r * r;
      }
      if (batch.want_signal || batch.want_force) record(sample);
    }
  }
  for (int l = 0; l < nb; ++l) {
    out.cost[static_cast<std::size_t>(s0 + l)] = cost[l];
    if (batch.want_end_state) {
      ModalState& e = out.end_state[static_cast<std::size_t>(s0 + l)];
      e.q.assign(static_cast<std::size_t>(M), 0.0);
      e.v.assign(static_cast<std::size_t>(M), 0.0);
      for (int i = 0; i < M; ++i) {
        e.q[static_cast<std::size_t>(i)] = q[i][l];
        e.v[static_cast<std::size_t>(i)] = v[i][l];
      }
    }
  }
}

class CpuBackend final : public ForwardBackend {
 public:
  explicit CpuBackend(int threads) : pool_(threads) {}
  CpuBackend(const CpuBackend&) = delete;
  CpuBackend& operator=(const CpuBackend&) = delete;
  std::string description() const override { return "cpu: " + std::to_string(pool_.size()) + " threads"; }

  void solve(const ForwardProblem& pb, const ForwardBatch& batch, ForwardOutput& out) override {
    detail::check_forward_batch(pb, batch, kMaxModes);
    const ModalModel& modal = *pb.modal;
    const Window& w = *pb.window;
    const int M = modal.n_modes(), N = w.n_samples(), S = batch.n_sets;
    const int n_model = static_cast<int>(force_model_parameters(pb.model).size());

    Setup setup{};
    setup.pb = &pb;
    setup.batch = &batch;
    setup.n_modes = M;
    setup.n_samples = N;
    setup.n_model_params = n_model;
    setup.substeps = pb.substeps;
    setup.dt = w.sample_period_s / pb.substeps;
    const StepCoefficients& st = *pb.step;
    setup.k = detail::make_mode_constants(modal, st);
    setup.tip = detail::tip_step_response(modal, st);
    setup.displacement = modal.sensor() == Sensor::displacement;
    if (!batch.drive_varies || w.drive.kind == DriveKind::sampled) {
      // An inversion solves many batches of one window: evaluate its drive once.
      DriveKey key{&w, &st, pb.substeps, N, w.t0_s, w.drive.kind, {}};
      for (int k = 0; k < 4; ++k) key.params[k] = batch.params[static_cast<std::size_t>(n_model + k) * S];
      if (!(key == drive_key_) || w.drive.kind == DriveKind::sampled) {
        drive_ = detail::make_shared_drive(modal, st, w, key.params, pb.substeps);
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
      if (nb <= 4) solve_block<4>(setup, s0, nb, out);
      else if (nb <= 8) solve_block<8>(setup, s0, nb, out);
      else solve_block<16>(setup, s0, nb, out);
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
  DriveKey drive_key_;
  detail::SharedDrive drive_;
};

}  // namespace

std::unique_ptr<ForwardBackend> make_cpu_backend(int threads) {
  if (threads <= 0) threads = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  return std::make_unique<CpuBackend>(threads);
}

int default_substeps(ForceModelKind model) {
  return (model == ForceModelKind::hertz || model == ForceModelKind::dmt || model == ForceModelKind::dmt_viscous) ? 4 : 1;
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
