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
    L.samples_per_step = detail::samples_per_step(pb, batch);
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
    L.held_drive = w.drive.kind != DriveKind::sine;
    L.resolution = detail::contact_resolution(modal, pb);
    const void* host_levels = upload_levels(modal, st, L.samples_per_step, P);
    L.d_levels = d_levels_.get();

    // Cached inputs: the window's samples and the shared drive change once per window, not per
    // batch (an inversion solves tens of batches per window).
    upload_deflection(w);
    L.d_deflection = d_deflection_.get();
    if (!L.per_set_drive) {
      upload_shared_drive(modal, st, w, batch, layout, K, L.samples_per_step, P, host_levels);
      L.sine = d_sine_;
      L.held = d_held_;
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
  // them), for the padded mode count P, uploaded when the modal model or the step changes.
  // Returns the levels on the host.
  const void* upload_levels(const ModalModel& modal, const StepCoefficients& st, int samples_per_step, int P) {
    const auto [levels, bytes] = levels_.get(P, modal, st, samples_per_step);
    const auto* first = static_cast<const std::byte*>(levels);
    h_levels_.assign(first, first + bytes);
    if (levels_valid_ && h_levels_ == levels_uploaded_) return levels;
    d_levels_.reserve(bytes);
    exec_.to_device(d_levels_.get(), h_levels_.data(), bytes, "cudaMemcpyAsync(step levels)");
    levels_uploaded_ = h_levels_;
    levels_valid_ = true;
    return levels;
  }

  // The shared drive (detail::make_shared_drive, as the CPU backend computes it), its arrays
  // packed into one device buffer and the views pointed at it.
  // host_levels: upload_levels' answer (the coarse step's constants first).
  void upload_shared_drive(const ModalModel& modal, const StepCoefficients& st, const Window& w,
                           const ForwardBatch& batch, const ParameterLayout& layout, int K, int samples_per_step,
                           int P, const void* host_levels) {
    const auto drive = FullParams(layout, batch.params, batch.n_sets, 0).drive();
    const double* dp = drive.data();
    key_scratch_.assign(modal, st, w, dp, K, samples_per_step, P);
    if (drive_valid_ && key_scratch_ == drive_key_) return;
    drive_valid_ = false;

    detail::SharedDrive d;
    // The coarse step's constants are the first of the levels.
    const auto make = [&](auto padded) {
      constexpr int Q = decltype(padded)::value;
      detail::make_shared_drive<Q>(*static_cast<const detail::StepConstants<Q>*>(host_levels), w, dp, K,
                                   samples_per_step, d);
    };
    switch (P) {
      case 1: make(std::integral_constant<int, 1>{}); break;
      case 2: make(std::integral_constant<int, 2>{}); break;
      case 4: make(std::integral_constant<int, 4>{}); break;
      case 8: make(std::integral_constant<int, 8>{}); break;
      case 16: make(std::integral_constant<int, 16>{}); break;
      default: make(std::integral_constant<int, 32>{}); break;
    }
    // One buffer, the arrays one after another; the views point into it.
    const auto arrays = d.arrays();
    std::size_t total = 0;
    for (const auto* a : arrays) total += a->size();
    h_drive_.assign(total, 0.0);
    std::vector<std::size_t> offset;
    std::size_t at = 0;
    for (const auto* a : arrays) {
      offset.push_back(at);
      std::copy(a->begin(), a->end(), h_drive_.begin() + static_cast<std::ptrdiff_t>(at));
      at += a->size();
    }
    d_drive_.reserve(std::max<std::size_t>(total, 1));
    exec_.to_device(d_drive_.get(), h_drive_.data(), total * sizeof(double), "cudaMemcpyAsync(shared drive)");
    const double* base = d_drive_.get();
    auto on_device = [&](const std::vector<double>& a) -> const double* {
      for (std::size_t k = 0; k < arrays.size(); ++k)
        if (arrays[k] == &a) return a.empty() ? nullptr : base + offset[k];
      TIPFORCE_DEMAND(false);
      return nullptr;
    };
    d_sine_ = d.sine;
    d_held_ = d.hold;
    detail::point_views(d, on_device, d_sine_, d_held_);
    drive_key_.swap(key_scratch_);
    drive_valid_ = true;
  }

  // The step levels of every padded mode count the kernel runs.
  class PaddedLevels {
   public:
    std::pair<const void*, std::size_t> get(int P, const ModalModel& modal, const StepCoefficients& st, int sps) {
      switch (P) {
        case 1: return of(l1_, modal, st, sps);
        case 2: return of(l2_, modal, st, sps);
        case 4: return of(l4_, modal, st, sps);
        case 8: return of(l8_, modal, st, sps);
        case 16: return of(l16_, modal, st, sps);
        default: return of(l32_, modal, st, sps);
      }
    }

   private:
    template <int P>
    static std::pair<const void*, std::size_t> of(detail::StepLevels<P>& levels, const ModalModel& modal,
                                                  const StepCoefficients& st, int samples_per_step) {
      return {levels.get(modal, st, samples_per_step), detail::kSubstepLevels * sizeof(detail::StepConstants<P>)};
    }
    detail::StepLevels<1> l1_;
    detail::StepLevels<2> l2_;
    detail::StepLevels<4> l4_;
    detail::StepLevels<8> l8_;
    detail::StepLevels<16> l16_;
    detail::StepLevels<32> l32_;
  };

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
  PaddedLevels levels_;
  std::vector<std::byte> h_levels_, levels_uploaded_;
  bool levels_valid_ = false;
  detail::SharedSineView d_sine_;  // views of the uploaded shared drive (device pointers)
  detail::SharedHeldView d_held_;
  // Host copies of what d_deflection_ / d_drive_ hold (the cache keys; kept alive for the copies).
  std::vector<double> h_deflection_, h_drive_;
  detail::SharedDriveKey drive_key_, key_scratch_;
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
