#pragma once
// The CPU backend's workers: run(n, fn) calls fn(0 .. n-1) across the threads, the caller being
// one of them, and returns when all calls are done.
//
// An inversion hands the pool a batch every few hundred microseconds with a few microseconds of
// its own work in between, and a batch of a few sets is only two or three blocks. Woken through a
// condition variable, a sleeping worker on this project's 2-core VM took ~80 us to start: a batch
// of two one-set blocks (~97 us each) took 174 us on two threads. So a worker that has finished
// spins for a while (spin_us) before it sleeps, and the blocks are claimed from a shared counter
// (the first free thread takes the next one) rather than dealt out in turn. Which thread solves a
// block does not change its result.
//
// A run is over when its calls are done, not when every worker has looked in: a worker asleep
// when a run begins (the first batch of a window, after the gap between windows) may take
// milliseconds to be scheduled on this VM, and the caller, having done the whole batch itself,
// waited for it (tipforced at 800 windows/s: windows cut in their first Jacobian batch, 8 solves
// and ~0.2 ms of work begun within 0.1 ms of receipt, were published 3-5 ms after it; with this,
// less than half as many windows reached the 1.5 ms budget). A worker claims a call together with
// the run it belongs to (one atomic ticket: the run's number and the next index), so one that
// wakes late finds its run over and claims nothing of the next.
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <exception>
#include <functional>
#include <mutex>
#include <thread>
#include <utility>
#include <vector>

#if defined(__x86_64__) || defined(__i386__)
#include <immintrin.h>
#endif

namespace tipforce::cpu {

class ThreadPool {
 public:
  // spin_us: how long an idle worker polls for the next run before it sleeps.
  explicit ThreadPool(int threads, double spin_us = 200) : spin_(std::chrono::duration<double, std::micro>(spin_us)) {
    for (int i = 1; i < threads; ++i) workers_.emplace_back([this] { work(); });
  }
  ~ThreadPool() {
    {
      std::lock_guard lock(mutex_);
      stop_ = true;
    }
    wake_.notify_all();
    for (auto& w : workers_) w.join();
  }
  ThreadPool(const ThreadPool&) = delete;
  ThreadPool& operator=(const ThreadPool&) = delete;

  int size() const { return static_cast<int>(workers_.size()) + 1; }

  void run(int n, const std::function<void(int)>& fn) {
    if (n <= 1 || workers_.empty()) {
      for (int i = 0; i < n; ++i) fn(i);
      return;
    }
    job_.store(&fn);
    n_jobs_.store(n);
    completed_.store(0);
    // Publishes the job: a worker that claims from this ticket sees job_ and n_jobs_ as set above.
    const std::uint64_t run = ((ticket_.load() >> 32) + 1) & kClosed;
    ticket_.store(run << 32);
    if (sleeping_.load() > 0) {
      // A worker that checked the ticket before the store is inside wait() by the time the mutex
      // is ours: the notification cannot fall between its check and its wait.
      std::lock_guard lock(mutex_);
      wake_.notify_all();
    }
    claim(run);
    spin_then_wait(done_, caller_sleeping_, [&] { return completed_.load() == n; });
    // Closed: a worker that loaded the ticket before this store (and may read the next run's
    // n_jobs_) fails its exchange; the next run cannot be claimed from this one's ticket.
    ticket_.store(run << 32 | kClosed);
    // A call that threw (on any thread) is rethrown here, once no thread holds fn any more.
    if (error_) std::rethrow_exception(std::exchange(error_, nullptr));
  }

 private:
  // Claims and runs calls of run `run` until none is left (or the run is over).
  void claim(std::uint64_t run) {
    for (;;) {
      std::uint64_t t = ticket_.load();
      int i = 0;
      do {
        if ((t >> 32) != run || (t & kClosed) >= static_cast<std::uint64_t>(n_jobs_.load())) return;
        i = static_cast<int>(t & kClosed);
      } while (!ticket_.compare_exchange_weak(t, t + 1));
      // Claimed call i of this run: the run cannot end before it is counted, so its job stands.
      try {
        (*job_.load())(i);
      } catch (...) {
        std::lock_guard lock(mutex_);
        if (!error_) error_ = std::current_exception();
      }
      if (completed_.fetch_add(1) + 1 == n_jobs_.load() && caller_sleeping_.load() > 0) {
        std::lock_guard lock(mutex_);
        done_.notify_all();
      }
    }
  }
  static void pause() {
#if defined(__x86_64__) || defined(__i386__)
    _mm_pause();
#else
    std::this_thread::yield();
#endif
  }
  // Polls `ready` for up to spin_, then sleeps on cv until it holds (or the pool stops).
  template <class Ready>
  void spin_then_wait(std::condition_variable& cv, std::atomic<int>& sleepers, Ready ready) {
    const auto until = std::chrono::steady_clock::now() + spin_;
    for (int k = 0; !ready(); ++k) {
      pause();
      if ((k & 255) == 255 && std::chrono::steady_clock::now() > until) {
        std::unique_lock lock(mutex_);
        sleepers.fetch_add(1);
        cv.wait(lock, [&] { return ready() || stop_; });
        sleepers.fetch_sub(1);
        return;
      }
    }
  }
  void work() {
    std::uint64_t seen = 0;
    for (;;) {
      spin_then_wait(wake_, sleeping_, [&] { return (ticket_.load() >> 32) != seen; });
      {
        std::lock_guard lock(mutex_);
        if (stop_) return;
      }
      seen = ticket_.load() >> 32;
      claim(seen);
    }
  }

  const std::chrono::duration<double, std::micro> spin_;
  std::vector<std::thread> workers_;
  std::mutex mutex_;
  std::condition_variable wake_, done_;
  std::atomic<const std::function<void(int)>*> job_{nullptr};
  std::atomic<int> n_jobs_{0}, completed_{0}, sleeping_{0}, caller_sleeping_{0};
  // The current run's number (high 32 bits) and its next call (low; kClosed once the run is over).
  static constexpr std::uint64_t kClosed = 0xffffffffu;
  std::atomic<std::uint64_t> ticket_{kClosed};
  bool stop_ = false;
  std::exception_ptr error_;  // the first exception of the current run (under mutex_)
};

}  // namespace tipforce::cpu
