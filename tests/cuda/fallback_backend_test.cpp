// FallbackBackend: a primary that fails hands the batch to the fallback (plain C++, no GPU needed).
#include <gtest/gtest.h>

#include <stdexcept>
#include <string>

#include "tipforce/fallback_backend.hpp"
#include "tipforce/tipforce.hpp"

namespace tipforce {
namespace {

// A primary that fails the way a lost GPU does (or succeeds, when told to).
class FakePrimary final : public ForwardBackend {
 public:
  enum class Mode { fail_runtime, fail_invalid, fail_unknown, succeed };
  explicit FakePrimary(Mode* mode, int* calls) : mode_(mode), calls_(calls) {}
  std::string description() const override { return "cuda: fake device"; }
  void solve(const ForwardProblem&, const ForwardBatch& batch, ForwardOutput& out) override {
    ++*calls_;
    switch (*mode_) {
      case Mode::fail_runtime: throw std::runtime_error("tipforce cuda: forward kernel: cudaErrorDeviceLost");
      case Mode::fail_invalid: throw std::invalid_argument("parameter array has the wrong size");
      case Mode::fail_unknown: throw 42;
      case Mode::succeed: out.cost.assign(static_cast<std::size_t>(batch.n_sets), -1.0); return;
    }
  }

 private:
  Mode* mode_;
  int* calls_;
};

struct Fixture {
  ModalModel modal;
  Window window;
  StepCoefficients step;
  std::vector<double> params;
  ModalState rest;
  ForwardBatch batch;
  Fixture()
      : modal(paper_probe_spec(4)),
        rest(ModalState::rest(4)) {
    window.sample_period_s = 1e-7;
    window.drive.kind = DriveKind::sine;
    window.drive.amplitude_m = 2e-9;
    window.drive.frequency_hz = 25600.0;
    window.deflection_m.assign(500, 1e-9);
    step = make_step_coefficients(modal, window.sample_period_s);
    params = {4.0, 5e-9, 2e-9, 25600.0, 0.0, 0.0};  // spring k, h, then the drive
    batch.n_sets = 1;
    batch.params = params;
    batch.initial = std::span<const ModalState>(&rest, 1);
    batch.want_signal = true;
  }
  ForwardProblem problem() const { return {&modal, &step, ForceModelKind::spring, &window, 1}; }
};

TEST(FallbackBackend, FailingPrimaryIsCountedAndTheBatchSolvedOnTheFallback) {
  Fixture fx;
  FakePrimary::Mode mode = FakePrimary::Mode::fail_runtime;
  int calls = 0;
  FallbackBackend backend(std::make_unique<FakePrimary>(&mode, &calls), make_cpu_backend(1));
  EXPECT_EQ(backend.description(), "cuda: fake device");
  EXPECT_EQ(backend.fallbacks(), 0u);
  EXPECT_EQ(backend.last_error(), "");

  ForwardOutput out, expect;
  backend.solve(fx.problem(), fx.batch, out);
  make_cpu_backend(1)->solve(fx.problem(), fx.batch, expect);
  EXPECT_EQ(calls, 1);
  EXPECT_EQ(backend.fallbacks(), 1u);
  EXPECT_NE(backend.last_error().find("cudaErrorDeviceLost"), std::string::npos) << backend.last_error();
  ASSERT_EQ(out.cost.size(), 1u);
  EXPECT_EQ(out.cost, expect.cost);
  EXPECT_EQ(out.signal, expect.signal);

  // Every batch tries the primary again: a device that comes back is used again.
  mode = FakePrimary::Mode::fail_unknown;
  backend.solve(fx.problem(), fx.batch, out);
  EXPECT_EQ(backend.fallbacks(), 2u);
  EXPECT_EQ(backend.last_error(), "unknown exception");
  EXPECT_EQ(out.cost, expect.cost);

  mode = FakePrimary::Mode::succeed;
  backend.solve(fx.problem(), fx.batch, out);
  EXPECT_EQ(calls, 3);
  EXPECT_EQ(backend.fallbacks(), 2u);
  EXPECT_EQ(out.cost, std::vector<double>{-1.0});
}

TEST(FallbackBackend, CallersMistakeIsRethrownNotFallenBackOn) {
  Fixture fx;
  FakePrimary::Mode mode = FakePrimary::Mode::fail_invalid;
  int calls = 0;
  FallbackBackend backend(std::make_unique<FakePrimary>(&mode, &calls), make_cpu_backend(1));
  ForwardOutput out;
  EXPECT_THROW(backend.solve(fx.problem(), fx.batch, out), std::invalid_argument);
  EXPECT_EQ(backend.fallbacks(), 0u);
}

TEST(FallbackBackend, RefusesNullBackends) {
  EXPECT_THROW(FallbackBackend(nullptr, make_cpu_backend(1)), std::invalid_argument);
  int calls = 0;
  FakePrimary::Mode mode = FakePrimary::Mode::succeed;
  EXPECT_THROW(FallbackBackend(std::make_unique<FakePrimary>(&mode, &calls), nullptr), std::invalid_argument);
}

}  // namespace
}  // namespace tipforce
