#pragma once
// Choosing a forward backend by name: "cpu", "cuda", or "auto" (the GPU if one works, else the CPU).
#include <memory>
#include <string>
#include <string_view>

#include "tipforce/forward.hpp"

namespace tipforce {

struct BackendChoice {
  std::unique_ptr<ForwardBackend> backend;
  std::string note;  // what was chosen and why, for the start-up log line
};

// Throws std::invalid_argument for an unknown name, and std::runtime_error when "cuda" is asked
// for and no working GPU (or no CUDA build) is there.
BackendChoice make_backend(std::string_view which, int cpu_threads = 0);

}  // namespace tipforce
