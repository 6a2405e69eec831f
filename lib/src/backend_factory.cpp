#include <stdexcept>
#include <string>

#include "tipforce/backend.hpp"
#ifdef TIPFORCE_HAVE_CUDA
#include "tipforce/cuda_backend.hpp"
#endif

namespace tipforce {

BackendChoice make_backend(std::string_view which, int cpu_threads) {
  if (which != "auto" && which != "cpu" && which != "cuda")
    throw std::invalid_argument("backend must be auto, cpu or cuda, got '" + std::string(which) + "'");
  std::string why_not_cuda;
  if (which != "cpu") {
#ifdef TIPFORCE_HAVE_CUDA
    if (auto gpu = make_cuda_backend(&why_not_cuda)) {
      std::string d = gpu->description();
      return {std::move(gpu), "backend " + d + " (asked for " + std::string(which) + ")"};
    }
#else
    why_not_cuda = "this build has no CUDA backend (configured without nvcc)";
#endif
    if (which == "cuda") throw std::runtime_error("backend cuda unavailable: " + why_not_cuda);
  }
  auto cpu = make_cpu_backend(cpu_threads);
  std::string note = "backend " + cpu->description();
  if (which == "auto") note += " (auto: no GPU: " + why_not_cuda + ")";
  return {std::move(cpu), note};
}

}  // namespace tipforce
