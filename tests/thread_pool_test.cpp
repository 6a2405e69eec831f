// The CPU backend's thread pool (lib/src/thread_pool.hpp): every call of a run exactly once, on
// whichever thread, the run over when its calls are (not when every worker has looked in), an
// exception rethrown to the caller. Workers that sleep at once (spin 0) wake late for runs that
// are already over: they must claim nothing of the next run.
#include <gtest/gtest.h>

#include <atomic>
#include <stdexcept>
#include <vector>

#include "thread_pool.hpp"

namespace tipforce::cpu {
namespace {

void expect_every_call_once(ThreadPool& pool, int runs) {
  std::vector<std::atomic<int>> calls(64);
  for (int r = 0; r < runs; ++r) {
    const int n = 2 + r % 63;
    for (auto& c : calls) c.store(0);
    pool.run(n, [&](int i) { calls[static_cast<std::size_t>(i)].fetch_add(1); });
    int wrong = 0;
    for (int i = 0; i < 64; ++i) wrong += calls[static_cast<std::size_t>(i)].load() != (i < n ? 1 : 0);
    ASSERT_EQ(wrong, 0) << "run " << r << " of " << n << " calls";
  }
}

TEST(ThreadPool, EveryCallOfEveryRunExactlyOnce) {
  for (double spin_us : {0.0, 200.0})
    for (int threads : {2, 3}) {
      ThreadPool pool(threads, spin_us);
      expect_every_call_once(pool, 20000);
    }
}

TEST(ThreadPool, ACallThatThrowsIsRethrownAndThePoolCarriesOn) {
  ThreadPool pool(2, 0.0);
  for (int r = 0; r < 200; ++r) {
    std::atomic<int> done{0};
    EXPECT_THROW(pool.run(8,
                          [&](int i) {
                            done.fetch_add(1);
                            if (i == r % 8) throw std::runtime_error("call failed");
                          }),
                 std::runtime_error);
    EXPECT_EQ(done.load(), 8);  // the other calls still ran
  }
  expect_every_call_once(pool, 1000);
}

}  // namespace
}  // namespace tipforce::cpu
