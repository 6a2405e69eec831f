#pragma once
// The CUDA forward backend (SPEC section 2): one GPU thread per parameter set, the window's time loop
// inside the kernel. Plain C++: no CUDA types here, so any translation unit may include it.
#include <memory>
#include <string>

#include "tipforce/forward.hpp"

namespace tipforce {

// The backend the service uses: the CUDA backend on device 0 wrapped in a FallbackBackend
// (tipforce/fallback_backend.hpp) whose fallback is the CPU backend, so that a batch on which the
// GPU fails (lost device, out of memory, ...) is still solved. Returns nullptr and says why in
// *why_not (when given) where there is no usable device, driver or kernel image. Never aborts.
std::unique_ptr<ForwardBackend> make_cuda_backend(std::string* why_not = nullptr);

// The bare CUDA backend on one device, without a fallback: its solve() throws std::runtime_error
// with the CUDA error string when the GPU fails, and std::invalid_argument (like the CPU backend)
// for a malformed problem or batch. Returns nullptr and says why where the device is unusable.
// description(): "cuda: <device name>".
std::unique_ptr<ForwardBackend> make_cuda_backend_unwrapped(std::string* why_not = nullptr, int device = 0);

// Number of usable CUDA devices; 0 (with the reason in *why_not) where there is none, no driver,
// or the runtime cannot start. Never throws.
int cuda_device_count(std::string* why_not = nullptr);

}  // namespace tipforce
