// The CUDA forward backend, host side: validation, preparation (with the library's helpers),
// device-resident workspace, one stream per backend. The kernel is behind launch_forward().
#include "tipforce/cuda_backend.hpp"

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstring>
#include <memory>
#include <mutex>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "cuda_resources.hpp"
#include "forward_kernel.hpp"
#include "host_emulation.hpp"
#include "tipforce/assert.hpp"
#include "tipforce/detail/forward_setup.hpp"
#include "tipforce/fallback_backend.hpp"

namespace tipforce {
namespace {

using cuda::check;

constexpr std::size_t kAlign = 256;  // bytes; section starts in the packed buffers
std::size_t align_up(std::size_t bytes) { return (bytes + kAlign - 1) / kAlign * kAlign; }

bool same_bytes(const std::vector<double>& a, const std::vector<double>& b) {
  return a.size() == b.size() && (a.empty() || std::memcmp(a.data(), b.data(), a.size() * sizeof(double)) == 0);
}

// Where the work runs: the GPU (device and pinned memory, one stream per backend) ...
class GpuExec {
 public:
  template <class T>
  using DeviceMemory = cuda::DeviceBuffer<T>;
  template <class T>
  using StagingMemory = cuda::PinnedBuffer<T>;

  explicit GpuExec(int device) : device_(device) {
    check(cudaSetDevice(device_), "cudaSetDevice");
    cudaDeviceProp prop{};
    check(cudaGetDeviceProperties(&prop, device_), "cudaGetDeviceProperties");
    name_ = prop.name;
    sm_count_ = prop.multiProcessorCount;
    check(cuda::forward_kernel_available(), "forward kernel for this device");
    stream_ = std::make_unique<cuda::Stream>();
  }
  ~GpuExec() { (void)cudaSetDevice(device_); }
  GpuExec(const GpuExec&) = delete;
  GpuExec& operator=(const GpuExec&) = delete;

  std::string description() const { return "cuda: " + name_; }
  int sm_count() const { return sm_count_; }
  void activate() { check(cudaSetDevice(device_), "cudaSetDevice"); }
  void to_device(void* d, const void* h, std::size_t bytes, const char* what) {
    check(cudaMemcpyAsync(d, h, bytes, cudaMemcpyHostToDevice, stream_->get()), what);
  }
  void to_host(void* h, const void* d, std::size_t bytes, const char* what) {
    check(cudaMemcpyAsync(h, d, bytes, cudaMemcpyDeviceToHost, stream_->get()), what);
  }
  void launch(const cuda::ForwardLaunch& launch) {
    check(cuda::launch_forward(launch, stream_->get()), "forward kernel launch");
  }
  void finish() { check(cudaStreamSynchronize(stream_->get()), "forward kernel"); }
  void recover() { (void)cudaGetLastError(); }  // clear a non-sticky error so the next call starts clean

 private:
  int device_;
  std::string name_;
  int sm_count_ = 1;
  std::unique_ptr<cuda::Stream> stream_;
};

// ... or the host: the same preparation, layouts and per-set code in host memory, to check all of
// it without a GPU.
template <class T>
class HostMemory {
 public:
  void reserve(std::size_t n) {
    if (n > capacity_) {
      p_ = std::make_unique<T[]>(n);
      capacity_ = n;
    }
  }
  T* get() const { return p_.get(); }

 private:
  std::unique_ptr<T[]> p_;
  std::size_t capacity_ = 0;
};

class HostExec {
 public:
  template <class T>
  using DeviceMemory = HostMemory<T>;
  template <class T>
  using StagingMemory = HostMemory<T>;

  std::string description() const { return "cuda (host emulation)"; }
  int sm_count() const { return 1; }
  void activate() {}
  void to_device(void* d, const void* h, std::size_t bytes, const char*) {
    if (bytes) std::memcpy(d, h, bytes);
  }
  void to_host(void* h, const void* d, std::size_t bytes, const char*) {
    if (bytes) std::memcpy(h, d, bytes);
  }
  void launch(const cuda::ForwardLaunch& launch) { check(cuda::run_forward_on_host(launch), "forward on host"); }
  void finish() {}
  void recover() {}
};

template <class Exec>
class CudaBackend final : public ForwardBackend {
 public:
  template <class... Args>
  explicit CudaBackend(Args&&... args) : exec_(std::forward<Args>(args)...) {}

  std::string description() const override { return exec_.description(); }

  // One batch at a time per backend (the calls are serialised); several backends run concurrently.
  void solve(const ForwardProblem& pb, const ForwardBatch& batch, ForwardOutput& out) override {
    validate(pb, batch);
    std::lock_guard lock(mutex_);
    try {
      run(pb, batch, out);
    } catch (...) {
      // The device copies of the cached inputs may be half written: upload them again next time.
      drive_valid_ = deflection_valid_ = false;
      exec_.recover();
      throw;
    }
  }

 private:
  // The CPU backend's checks, with its messages (std::invalid_argument: the caller's mistake).
  static void validate(const ForwardProblem& pb, const ForwardBatch& batch) {
    detail::check_forward_batch(pb, batch, cuda::kMaxModes);
  }

  void run(const ForwardProblem& pb, const ForwardBatch& batch, ForwardOutput& out) {
    exec_.activate();
    const ModalModel& modal = *pb.modal;
    const StepCoefficients& st = *pb.step;
    const Window& w = *pb.window;
    const int M = modal.n_modes(), P = cuda::padded_modes(M), N = w.n_samples(), S = batch.n_sets;
    const int K = pb.substeps;
    const ParameterLayout layout(pb.model);
    const std::size_t uS = static_cast<std::size_t>(S), uN = static_cast<std::size_t>(N);
    const std::size_t uP = static_cast<std::size_t>(P), uM = static_cast<std::size_t>(M);

    cuda::ForwardLaunch L{};
    L.n_sets = S;
    L.n_samples = N;
    L.substeps = K;
    L.n_modes = M;
    L.sm_count = exec_.sm_count();
    L.model = static_cast<int>(pb.model);
    L.want_signal = batch.want_signal;
    L.want_force = batch.want_force;
    L.want_end_state = batch.want_end_state;
    L.displacement = modal.sensor() == Sensor::displacement;
    L.t0_s = w.t0_s;
    L.sample_period_s = w.sample_period_s;
    L.drive_kind = static_cast<int>(w.drive.kind);
    L.per_set_drive = batch.drive_varies && w.drive.kind != DriveKind::sampled;
    L.resolution = detail::contact_resolution(modal, pb);
    upload_levels(modal, st, P);
    L.d_levels = d_levels_.get();

    // Cached inputs: the window's samples and the shared drive change once per window, not per
    // batch (an inversion solves tens of batches per window).
    upload_deflection(w);
    L.d_deflection = d_deflection_.get();
    if (!L.per_set_drive) {
      upload_shared_drive(modal, st, w, batch, layout, K, P);
      const std::size_t steps = uN * static_cast<std::size_t>(K);
      const std::size_t samples = w.drive.kind == DriveKind::sampled ? uN + 1 : 0;
      const double* d = d_drive_.get();
      L.d_y = d;
      L.d_ydot = d + steps + 1;
      L.d_dq = d + 2 * (steps + 1);
      L.d_dv = L.d_dq + steps * uP;
      L.drive = drive_fn_;
      if (samples) {
        L.drive.ys = L.d_dv + steps * uP;
        L.drive.vs = L.drive.ys + samples;
        L.drive.as = L.drive.vs + samples;
      }
    } else {
      double dp[4] = {0, 0, 0, 0};
      L.drive = detail::analytic_drive(w, dp);
    }

    // Per-batch inputs, packed into one staging buffer and sent with one copy.
    const std::size_t n_init = batch.initial.size();
    L.n_init = static_cast<int>(n_init);
    const std::size_t lane_bytes = align_up(uS * sizeof(detail::LaneForce));
    const std::size_t drive_bytes = L.per_set_drive ? align_up(4 * uS * sizeof(double)) : 0;
    const std::size_t init_bytes = align_up(2 * uP * n_init * sizeof(double));
    const std::size_t in_bytes = lane_bytes + drive_bytes + init_bytes;
    h_in_.reserve(in_bytes);
    d_in_.reserve(in_bytes);
    std::byte* h = h_in_.get();
    auto* h_lane = reinterpret_cast<detail::LaneForce*>(h);
    for (int s = 0; s < S; ++s) h_lane[s] = detail::lane_force_of_set(pb.model, batch, s);
    if (L.per_set_drive) {
      auto* h_drive = reinterpret_cast<double*>(h + lane_bytes);
      for (int s = 0; s < S; ++s) {
        const auto dp = FullParams(layout, batch.params, S, s).drive();
        for (std::size_t k = 0; k < dp.size(); ++k) h_drive[k * uS + static_cast<std::size_t>(s)] = dp[k];
      }
    }
    auto* h_init = reinterpret_cast<double*>(h + lane_bytes + drive_bytes);
    for (std::size_t s = 0; s < n_init; ++s) {
      const ModalState& init = batch.initial[s];
      for (std::size_t i = 0; i < uP; ++i) {
        const bool real = i < uM;
        h_init[i * n_init + s] = real ? init.q[i] : 0.0;
        h_init[(uP + i) * n_init + s] = real ? init.v[i] : 0.0;
      }
    }
    exec_.to_device(d_in_.get(), h, in_bytes, "cudaMemcpyAsync(batch inputs)");
    L.d_lane = reinterpret_cast<const detail::LaneForce*>(d_in_.get());
    L.d_drive_params = L.per_set_drive ? reinterpret_cast<const double*>(d_in_.get() + lane_bytes) : nullptr;
    L.d_initial = reinterpret_cast<const double*>(d_in_.get() + lane_bytes + drive_bytes);

    // Outputs, packed so that the wanted ones are contiguous: one copy back.
    const std::size_t trace = uS * uN;
    const std::size_t o_cost = 0;
    const std::size_t o_end = o_cost + uS;
    const std::size_t o_signal = o_end + (batch.want_end_state ? 2 * uP * uS : 0);
    const std::size_t o_force = o_signal + (batch.want_signal ? trace : 0);
    const std::size_t o_tip = o_force + (batch.want_force ? trace : 0);
    const std::size_t n_out = o_tip + (batch.want_force ? trace : 0);
    d_out_.reserve(n_out);
    h_out_.reserve(n_out);
    double* d_out = d_out_.get();
    L.d_cost = d_out + o_cost;
    L.d_end = batch.want_end_state ? d_out + o_end : nullptr;
    L.d_signal = batch.want_signal ? d_out + o_signal : nullptr;
    L.d_force = batch.want_force ? d_out + o_force : nullptr;
    L.d_tip_z = batch.want_force ? d_out + o_tip : nullptr;

    exec_.launch(L);
    exec_.to_host(h_out_.get(), d_out, n_out * sizeof(double), "cudaMemcpyAsync(outputs)");
    exec_.finish();

    // Into the caller's output, as the CPU backend fills it.
    const double* ho = h_out_.get();
    out.cost.assign(ho + o_cost, ho + o_cost + uS);
    if (batch.want_signal) out.signal.assign(ho + o_signal, ho + o_signal + trace);
    if (batch.want_force) {
      out.force_n.assign(ho + o_force, ho + o_force + trace);
      out.tip_z_m.assign(ho + o_tip, ho + o_tip + trace);
    }
    if (batch.want_end_state) {
      out.end_state.assign(uS, ModalState{});
      const double* e = ho + o_end;
      for (std::size_t s = 0; s < uS; ++s) {
        ModalState& end = out.end_state[s];
        end.q.resize(uM);
        end.v.resize(uM);
        for (std::size_t i = 0; i < uM; ++i) {
          end.q[i] = e[i * uS + s];
          end.v[i] = e[(uP + i) * uS + s];
        }
      }
    }
  }

  void upload_deflection(const Window& w) {
    if (deflection_valid_ && same_bytes(w.deflection_m, h_deflection_)) return;
    deflection_valid_ = false;
    h_deflection_ = w.deflection_m;
    d_deflection_.reserve(h_deflection_.size());
    exec_.to_device(d_deflection_.get(), h_deflection_.data(), h_deflection_.size() * sizeof(double),
                    "cudaMemcpyAsync(deflection)");
    deflection_valid_ = true;
  }

  // The coarse step's constants and its refinements (detail::StepLevels, as the CPU backend uses
  // them), padded to P modes, uploaded when the modal model or the step changes.
  void upload_levels(const ModalModel& modal, const StepCoefficients& st, int P) {
    const detail::ModeConstants* levels = levels_.get(modal, st);
    const std::size_t bytes = static_cast<std::size_t>(detail::kSubstepLevels) * padded_level_bytes(P);
    h_levels_.assign(bytes, std::byte{0});
    for (int j = 0; j < detail::kSubstepLevels; ++j) pad_level(levels[j], P, h_levels_.data() + j * padded_level_bytes(P));
    if (levels_valid_ && h_levels_ == levels_uploaded_) return;
    d_levels_.reserve(bytes);
    exec_.to_device(d_levels_.get(), h_levels_.data(), bytes, "cudaMemcpyAsync(step levels)");
    levels_uploaded_ = h_levels_;
    levels_valid_ = true;
  }
  static std::size_t padded_level_bytes(int P) {
    switch (P) {
      case 1: return sizeof(detail::StepConstants<1>);
      case 2: return sizeof(detail::StepConstants<2>);
      case 4: return sizeof(detail::StepConstants<4>);
      case 8: return sizeof(detail::StepConstants<8>);
      case 16: return sizeof(detail::StepConstants<16>);
      default: return sizeof(detail::StepConstants<32>);
    }
  }
  template <int P>
  static void pad_level_to(const detail::ModeConstants& c, std::byte* out) {
    detail::StepConstants<P> p{};
    for (int i = 0; i < P; ++i) {
      p.a00[i] = c.a00[i]; p.a01[i] = c.a01[i]; p.a10[i] = c.a10[i]; p.a11[i] = c.a11[i];
      p.cs_q[i] = c.cs_q[i]; p.cs_v[i] = c.cs_v[i]; p.ce_q[i] = c.ce_q[i]; p.ce_v[i] = c.ce_v[i];
      p.phi[i] = c.phi[i]; p.gain[i] = c.gain[i]; p.gamma[i] = c.gamma[i];
      p.curv_q[i] = c.curv_q[i]; p.curv_v[i] = c.curv_v[i];
      p.wq0[i] = c.wq0[i]; p.wv0[i] = c.wv0[i]; p.wqm[i] = c.wqm[i]; p.wvm[i] = c.wvm[i];
      p.wq1[i] = c.wq1[i]; p.wv1[i] = c.wv1[i];
    }
    p.tip = c.tip;
    p.h_s = c.h_s;
    std::memcpy(out, &p, sizeof p);
  }
  static void pad_level(const detail::ModeConstants& c, int P, std::byte* out) {
    switch (P) {
      case 1: return pad_level_to<1>(c, out);
      case 2: return pad_level_to<2>(c, out);
      case 4: return pad_level_to<4>(c, out);
      case 8: return pad_level_to<8>(c, out);
      case 16: return pad_level_to<16>(c, out);
      default: return pad_level_to<32>(c, out);
    }
  }

  // The shared drive (detail::make_shared_drive, as the CPU backend computes it), laid out for
  // the kernel: y[0..NK], ydot[0..NK], dq and dv per step and padded mode, then a sampled drive's
  // per-sample base (ys, vs, as).
  void upload_shared_drive(const ModalModel& modal, const StepCoefficients& st, const Window& w,
                           const ForwardBatch& batch, const ParameterLayout& layout, int K, int P) {
    const int M = modal.n_modes(), N = w.n_samples();
    const auto drive = FullParams(layout, batch.params, batch.n_sets, 0).drive();
    const double* dp = drive.data();
    // Everything the drive arrays depend on, compared bit for bit with what was uploaded last.
    key_scratch_.clear();
    for (double x : {static_cast<double>(w.drive.kind), w.t0_s, w.sample_period_s, static_cast<double>(N),
                     static_cast<double>(K), static_cast<double>(M), static_cast<double>(P), st.dt_s})
      key_scratch_.push_back(x);
    if (w.drive.kind == DriveKind::sampled)
      key_scratch_.insert(key_scratch_.end(), w.drive.base_m.begin(), w.drive.base_m.end());
    else
      key_scratch_.insert(key_scratch_.end(), dp, dp + 4);
    for (int i = 0; i < M; ++i)
      for (double x : {modal.modes()[static_cast<std::size_t>(i)].gamma, st.wq0[i], st.wv0[i], st.wqm[i], st.wvm[i],
                       st.wq1[i], st.wv1[i]})
        key_scratch_.push_back(x);
    if (drive_valid_ && same_bytes(key_scratch_, drive_key_)) return;
    drive_valid_ = false;

    detail::SharedDrive d;
    detail::make_shared_drive(modal, st, w, dp, K, d);
    drive_fn_ = d.fn;
    const std::size_t steps = static_cast<std::size_t>(N) * static_cast<std::size_t>(K);
    const std::size_t uP = static_cast<std::size_t>(P), uM = static_cast<std::size_t>(M);
    const std::size_t samples = d.ys.size();
    h_drive_.assign(2 * (steps + 1) + 2 * steps * uP + 3 * samples, 0.0);
    auto out = h_drive_.begin();
    out = std::copy(d.y_m.begin(), d.y_m.end(), out);
    out = std::copy(d.ydot_m_per_s.begin(), d.ydot_m_per_s.end(), out);
    double* dq = h_drive_.data() + 2 * (steps + 1);
    double* dv = dq + steps * uP;
    for (std::size_t j = 0; j < steps; ++j)
      for (std::size_t i = 0; i < uM; ++i) {
        dq[j * uP + i] = d.dq[j * uM + i];
        dv[j * uP + i] = d.dv[j * uM + i];
      }
    out = h_drive_.begin() + static_cast<std::ptrdiff_t>(2 * (steps + 1) + 2 * steps * uP);
    out = std::copy(d.ys.begin(), d.ys.end(), out);
    out = std::copy(d.vs.begin(), d.vs.end(), out);
    std::copy(d.as.begin(), d.as.end(), out);
    d_drive_.reserve(h_drive_.size());
    exec_.to_device(d_drive_.get(), h_drive_.data(), h_drive_.size() * sizeof(double), "cudaMemcpyAsync(shared drive)");
    drive_key_.swap(key_scratch_);
    drive_valid_ = true;
  }

  // Declared first, destroyed last: the workspace below is freed while its device is current.
  Exec exec_;
  std::mutex mutex_;

  // Workspace: grows as needed, reused across calls.
  typename Exec::template StagingMemory<std::byte> h_in_;
  typename Exec::template DeviceMemory<std::byte> d_in_;
  typename Exec::template StagingMemory<double> h_out_;
  typename Exec::template DeviceMemory<double> d_out_;
  typename Exec::template DeviceMemory<double> d_deflection_, d_drive_;
  typename Exec::template DeviceMemory<std::byte> d_levels_;
  detail::StepLevels levels_;
  std::vector<std::byte> h_levels_, levels_uploaded_;
  bool levels_valid_ = false;
  detail::DriveFunction drive_fn_;
  // Host copies of what d_deflection_ / d_drive_ hold (the cache keys; kept alive for the copies).
  std::vector<double> h_deflection_, h_drive_, drive_key_, key_scratch_;
  bool deflection_valid_ = false, drive_valid_ = false;
};

std::string cuda_error_text(cudaError_t e) { return std::string(cudaGetErrorName(e)) + ": " + cudaGetErrorString(e); }

}  // namespace

int cuda_device_count(std::string* why_not) {
  int n = 0;
  const cudaError_t e = cudaGetDeviceCount(&n);
  if (e != cudaSuccess) {
    (void)cudaGetLastError();
    if (why_not) *why_not = "cudaGetDeviceCount failed: " + cuda_error_text(e);
    return 0;
  }
  if (n <= 0 && why_not) *why_not = "no CUDA device";
  return std::max(n, 0);
}

std::unique_ptr<ForwardBackend> make_cuda_backend_unwrapped(std::string* why_not, int device) {
  std::string why;
  const int n = cuda_device_count(&why);
  if (n > 0 && (device < 0 || device >= n))
    why = "CUDA device " + std::to_string(device) + " not present (" + std::to_string(n) + " devices)";
  if (n > 0 && device >= 0 && device < n) {
    try {
      return std::make_unique<CudaBackend<GpuExec>>(device);
    } catch (const std::exception& e) {
      (void)cudaGetLastError();
      why = e.what();
    }
  }
  if (why_not) *why_not = why;
  return nullptr;
}

std::unique_ptr<ForwardBackend> make_cuda_backend(std::string* why_not) {
  auto gpu = make_cuda_backend_unwrapped(why_not, 0);
  if (!gpu) return nullptr;
  return std::make_unique<FallbackBackend>(std::move(gpu), make_cpu_backend());
}

namespace cuda {
std::unique_ptr<ForwardBackend> make_host_emulation_backend() { return std::make_unique<CudaBackend<HostExec>>(); }
}  // namespace cuda

}  // namespace tipforce
