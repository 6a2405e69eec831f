#pragma once
// A bounded multi-producer / single-consumer queue between tipforced's IO thread and its solver
// thread. The producer never blocks: when the queue is full, push() drops the oldest waiting item
// and hands it back so that the caller can count it. The consumer blocks in pop() until an item
// arrives or the queue is closed.
#include <condition_variable>
#include <cstddef>
#include <deque>
#include <mutex>
#include <optional>
#include <utility>
#include <vector>

namespace tipforce::daemon {

template <typename T>
class BoundedQueue {
 public:
  explicit BoundedQueue(std::size_t capacity) : capacity_(capacity == 0 ? 1 : capacity) {}

  BoundedQueue(const BoundedQueue&) = delete;
  BoundedQueue& operator=(const BoundedQueue&) = delete;

  std::size_t capacity() const { return capacity_; }

  // Adds an item. If the queue was full, the oldest waiting item is removed and returned (the
  // caller counts it as dropped). A closed queue refuses the item and returns it.
  std::optional<T> push(T item) {
    std::optional<T> dropped;
    {
      std::lock_guard lock(mutex_);
      if (closed_) return std::optional<T>(std::move(item));
      if (items_.size() >= capacity_) {
        dropped.emplace(std::move(items_.front()));
        items_.pop_front();
      }
      items_.push_back(std::move(item));
    }
    ready_.notify_one();
    return dropped;
  }

  // Adds an item only if there is room; returns false (and leaves the item alone) when the queue
  // is full or closed. Used where back-pressure replaces dropping (file input).
  bool try_push(T& item) {
    {
      std::lock_guard lock(mutex_);
      if (closed_ || items_.size() >= capacity_) return false;
      items_.push_back(std::move(item));
    }
    ready_.notify_one();
    return true;
  }

  // Blocks until an item is there (returns it) or the queue is closed and empty (nullopt).
  std::optional<T> pop() {
    std::unique_lock lock(mutex_);
    ready_.wait(lock, [&] { return closed_ || !items_.empty(); });
    if (items_.empty()) return std::nullopt;
    T item = std::move(items_.front());
    items_.pop_front();
    return item;
  }

  // No more pushes; pop() keeps returning what is left, then nullopt.
  void close() {
    {
      std::lock_guard lock(mutex_);
      closed_ = true;
    }
    ready_.notify_all();
  }

  // Closes the queue and takes every item still waiting (the consumer finishes what it holds).
  std::vector<T> close_and_take() {
    std::vector<T> left;
    {
      std::lock_guard lock(mutex_);
      closed_ = true;
      left.reserve(items_.size());
      for (auto& item : items_) left.push_back(std::move(item));
      items_.clear();
    }
    ready_.notify_all();
    return left;
  }

  std::size_t size() const {
    std::lock_guard lock(mutex_);
    return items_.size();
  }
  bool full() const {
    std::lock_guard lock(mutex_);
    return items_.size() >= capacity_;
  }
  bool closed() const {
    std::lock_guard lock(mutex_);
    return closed_;
  }

 private:
  const std::size_t capacity_;
  mutable std::mutex mutex_;
  std::condition_variable ready_;
  std::deque<T> items_;
  bool closed_ = false;
};

}  // namespace tipforce::daemon
