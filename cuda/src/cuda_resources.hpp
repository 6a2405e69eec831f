#pragma once
// Error checking and RAII owners for CUDA resources (host code; no kernels). Every CUDA call in
// business code goes through check(); nothing there calls cudaFree / cudaFreeHost itself.
#include <cuda_runtime_api.h>

#include <cstddef>
#include <stdexcept>
#include <string>
#include <utility>

namespace tipforce::cuda {

// A CUDA runtime error, with the call that failed and CUDA's own error name and string.
class CudaError : public std::runtime_error {
 public:
  CudaError(cudaError_t code, const std::string& what)
      : std::runtime_error("tipforce cuda: " + what + ": " + cudaGetErrorName(code) + ": " + cudaGetErrorString(code)),
        code_(code) {}
  cudaError_t code() const { return code_; }

 private:
  cudaError_t code_;
};

inline void check(cudaError_t code, const char* what) {
  if (code != cudaSuccess) throw CudaError(code, what);
}

// Device memory of n elements of T; grows on demand, never shrinks; contents are not kept.
template <class T>
class DeviceBuffer {
 public:
  DeviceBuffer() = default;
  DeviceBuffer(const DeviceBuffer&) = delete;
  DeviceBuffer& operator=(const DeviceBuffer&) = delete;
  ~DeviceBuffer() { release(); }

  // Makes room for at least n elements (with some headroom, so that slowly growing requests do
  // not reallocate every call). Must not be called while the buffer is in use by queued work.
  void reserve(std::size_t n) {
    if (n <= capacity_) return;
    release();
    const std::size_t want = n + n / 4;
    void* p = nullptr;
    check(cudaMalloc(&p, want * sizeof(T)), "cudaMalloc");
    d_ = static_cast<T*>(p);
    capacity_ = want;
  }
  T* get() const { return d_; }
  std::size_t capacity() const { return capacity_; }

 private:
  void release() noexcept {
    if (d_) (void)cudaFree(d_);  // an error here (lost device) leaves nothing to do
    d_ = nullptr;
    capacity_ = 0;
  }
  T* d_ = nullptr;
  std::size_t capacity_ = 0;
};

// Page-locked host memory (fast, asynchronous copies); grows on demand, contents not kept.
template <class T>
class PinnedBuffer {
 public:
  PinnedBuffer() = default;
  PinnedBuffer(const PinnedBuffer&) = delete;
  PinnedBuffer& operator=(const PinnedBuffer&) = delete;
  ~PinnedBuffer() { release(); }

  void reserve(std::size_t n) {
    if (n <= capacity_) return;
    release();
    const std::size_t want = n + n / 4;
    void* p = nullptr;
    check(cudaMallocHost(&p, want * sizeof(T)), "cudaMallocHost");
    h_ = static_cast<T*>(p);
    capacity_ = want;
  }
  T* get() const { return h_; }
  std::size_t capacity() const { return capacity_; }

 private:
  void release() noexcept {
    if (h_) (void)cudaFreeHost(h_);
    h_ = nullptr;
    capacity_ = 0;
  }
  T* h_ = nullptr;
  std::size_t capacity_ = 0;
};

// A non-blocking stream on the current device.
class Stream {
 public:
  Stream() { check(cudaStreamCreateWithFlags(&s_, cudaStreamNonBlocking), "cudaStreamCreateWithFlags"); }
  Stream(const Stream&) = delete;
  Stream& operator=(const Stream&) = delete;
  ~Stream() {
    if (s_) (void)cudaStreamDestroy(s_);
  }
  cudaStream_t get() const { return s_; }

 private:
  cudaStream_t s_ = nullptr;
};

}  // namespace tipforce::cuda
