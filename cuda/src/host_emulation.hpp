#pragma once
// The CUDA backend's host side (preparation, cached inputs, packed layouts, output unpacking) with
// the kernel's per-set code run on the host instead of a GPU: checks everything but the device
// itself on machines without one. Slow (one thread); for tests.
#include <memory>

#include "tipforce/forward.hpp"

namespace tipforce::cuda {

std::unique_ptr<ForwardBackend> make_host_emulation_backend();

}  // namespace tipforce::cuda
