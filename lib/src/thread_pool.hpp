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
    job_ = &fn;
    n_jobs_ = n;
    next_.store(0);
    pending_.store(static_cast<int>(workers_.size()));
    generation_.fetch_add(1);  // publishes job_ and n_jobs_ (sequentially consistent)
    if (sleeping_.load() > 0) {
      // A worker that checked the generation before the increment is inside wait() by the time
      // the mutex is ours: the notification cannot fall between its check and its wait.
      std::lock_guard lock(mutex_);
      wake_.notify_all();
    }
    claim(fn, n);
    wait_for_workers();
    job_ = nullptr;
    // A call that threw (on any thread) is rethrown here, once no thread holds fn any more.
    if (error_) std::rethrow_exception(std::exchange(error_, nullptr));
  }

 private:
  void claim(const std::function<void(int)>& fn, int n) {
    for (int i = next_.fetch_add(1); i < n; i = next_.fetch_add(1)) {
      try {
        fn(i);
      } catch (...) {
        std::lock_guard lock(mutex_);
        if (!error_) error_ = std::current_exception();
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
  void wait_for_workers() {
    spin_then_wait(done_, caller_sleeping_, [&] { return pending_.load() == 0; });
  }
  void work() {
    std::uint64_t seen = 0;
    for (;;) {
      spin_then_wait(wake_, sleeping_, [&] { return generation_.load() != seen; });
      {
        std::lock_guard lock(mutex_);
        if (stop_) return;
      }
      seen = generation_.load();
      claim(*job_, n_jobs_);
      if (pending_.fetch_sub(1) == 1 && caller_sleeping_.load() > 0) {
        std::lock_guard lock(mutex_);
        done_.notify_all();
      }
    }
  }

  const std::chrono::duration<double, std::micro> spin_;
  std::vector<std::thread> workers_;
  std::mutex mutex_;
  std::condition_variable wake_, done_;
  const std::function<void(int)>* job_ = nullptr;
  int n_jobs_ = 0;
  std::atomic<int> next_{0}, pending_{0}, sleeping_{0}, caller_sleeping_{0};
  std::atomic<std::uint64_t> generation_{0};
  bool stop_ = false;
  std::exception_ptr error_;  // the first exception of the current run (under mutex_)
};

}  // namespace tipforce::cpu
