#include "tipforce/fallback_backend.hpp"

#include <exception>
#include <stdexcept>
#include <utility>

namespace tipforce {

FallbackBackend::FallbackBackend(std::unique_ptr<ForwardBackend> primary, std::unique_ptr<ForwardBackend> fallback)
    : primary_(std::move(primary)), fallback_(std::move(fallback)) {
  if (!primary_ || !fallback_) throw std::invalid_argument("FallbackBackend: primary and fallback must be non-null");
}

std::string FallbackBackend::description() const { return primary_->description(); }

std::string FallbackBackend::last_error() const {
  std::lock_guard lock(error_mutex_);
  return last_error_;
}

void FallbackBackend::solve(const ForwardProblem& problem, const ForwardBatch& batch, ForwardOutput& out) {
  std::string error;
  try {
    primary_->solve(problem, batch, out);
    return;
  } catch (const std::invalid_argument&) {
    throw;  // the batch itself is wrong: the fallback would refuse it as well
  } catch (const std::exception& e) {
    error = e.what();
  } catch (...) {
    error = "unknown exception";
  }
  fallbacks_.fetch_add(1, std::memory_order_relaxed);
  {
    std::lock_guard lock(error_mutex_);
    last_error_ = std::move(error);
  }
  fallback_->solve(problem, batch, out);
}

}  // namespace tipforce
