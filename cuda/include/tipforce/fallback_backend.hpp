#pragma once
// A backend that falls back to another when the first one fails: the GPU backend first, the CPU
// backend for any batch on which the GPU throws. Plain C++; no CUDA dependency.
#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>

#include "tipforce/forward.hpp"

namespace tipforce {

class FallbackBackend final : public ForwardBackend {
 public:
  // Both must be non-null (std::invalid_argument otherwise).
  FallbackBackend(std::unique_ptr<ForwardBackend> primary, std::unique_ptr<ForwardBackend> fallback);

  // The primary's description: what the service normally runs on.
  std::string description() const override;

  // Solves on the primary; if it throws anything but std::invalid_argument (a caller's mistake,
  // which the fallback would refuse too and which is rethrown as is), counts the fallback,
  // remembers the error and solves the same batch on the fallback. Logs nothing.
  void solve(const ForwardProblem& problem, const ForwardBatch& batch, ForwardOutput& out) override;

  // Batches solved on the fallback so far; readable from any thread.
  std::uint64_t fallbacks() const { return fallbacks_.load(std::memory_order_relaxed); }
  // The primary's most recent error ("" before the first); readable from any thread.
  std::string last_error() const;

  ForwardBackend& primary() { return *primary_; }
  ForwardBackend& fallback() { return *fallback_; }

 private:
  std::unique_ptr<ForwardBackend> primary_, fallback_;
  std::atomic<std::uint64_t> fallbacks_{0};
  mutable std::mutex error_mutex_;
  std::string last_error_;
};

}  // namespace tipforce
