#pragma once
// A small persistent thread pool and parallel_for. Work items are dealt out
// dynamically (an atomic counter) so uneven items, such as tiles with very
// different Gaussian counts, balance across threads. The calling thread works
// too. A call made while the pool is busy (nested, or from another thread) runs
// inline rather than waiting, so parallel_for never deadlocks.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <exception>
#include <functional>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

#include "orbitforge/core/config.hpp"
#include "orbitforge/core/error.hpp"
#include "orbitforge/core/limits.hpp"

namespace orbitforge {

inline int hardware_threads() {
  const unsigned n = std::thread::hardware_concurrency();
  return n == 0 ? 1 : int(n);
}

// 0 means "the default": ORBITFORGE_DEFAULT_THREADS if set, else all hardware
// threads, either at most Limits::max_threads. An explicit count over that limit
// is refused (Error naming `what` and the limit).
inline int resolve_threads(int requested, const char* what = "thread count") {
  if (requested > 0) {
    check_thread_count(requested, what);
    return requested;
  }
  const int max = limits().max_threads;
  if (ORBITFORGE_DEFAULT_THREADS > 0) return std::min(int(ORBITFORGE_DEFAULT_THREADS), max);
  return std::min(hardware_threads(), max);
}

class ThreadPool {
 public:
  // Either every thread starts, or the ones started are stopped and joined and
  // Error says which one failed (a throw with workers still running would leave
  // them waiting on members being destroyed: a deadlock without a message).
  explicit ThreadPool(int threads) : threads_(std::max(1, threads)) {
    check_thread_count(threads_, "ThreadPool");
    workers_.reserve(std::size_t(threads_ - 1));
    for (int w = 1; w < threads_; ++w) {
      try {
        workers_.emplace_back([this, w] { worker_loop(w); });
      } catch (const std::exception& e) {
        stop_and_join();
        // Thread 1 is the caller's; worker w is thread w + 1.
        fail("ThreadPool: could not start thread ", w + 1, " of ", threads_, ": ", e.what(),
             " (lower the thread count, or raise the process limits: ulimit -u, ulimit -v)");
      }
    }
  }
  ~ThreadPool() { stop_and_join(); }
  ThreadPool(const ThreadPool&) = delete;
  ThreadPool& operator=(const ThreadPool&) = delete;

  int size() const { return threads_; }

  // Calls fn(i, worker) for every i in [0, n), worker in [0, size()).
  // Blocks until all items are done; rethrows the first exception thrown by fn.
  void run(std::size_t n, const std::function<void(std::size_t, int)>& fn) {
    if (n == 0) return;
    std::unique_lock<std::mutex> busy(busy_, std::try_to_lock);
    if (threads_ == 1 || n == 1 || !busy.owns_lock()) {
      for (std::size_t i = 0; i < n; ++i) fn(i, 0);
      return;
    }
    {
      std::lock_guard<std::mutex> lock(mutex_);
      job_ = &fn;
      count_ = n;
      next_.store(0);
      active_.store(threads_ - 1);
      error_ = nullptr;
      generation_.fetch_add(1, std::memory_order_release);
    }
    wake_.notify_all();
    work(0);
    if (!spin_until([this] { return active_.load(std::memory_order_acquire) == 0; })) {
      std::unique_lock<std::mutex> lock(mutex_);
      done_.wait(lock, [this] { return active_.load() == 0; });
    }
    job_ = nullptr;
    if (error_) std::rethrow_exception(error_);
  }

 private:
  // Calls and items come back to back in training (tens per step): a worker that
  // went to sleep costs a wake-up (~10 us each way on a VM) every call, so both
  // sides spin for a short while before blocking.
  template <class Pred>
  static bool spin_until(Pred&& done) {
    using clock = std::chrono::steady_clock;
    const auto deadline = clock::now() + std::chrono::microseconds(50);
    for (int i = 1;; ++i) {
      if (done()) return true;
#if defined(__x86_64__) || defined(__i386__)
      __builtin_ia32_pause();
#endif
      if (i % 64 == 0 && clock::now() > deadline) return done();
    }
  }
  void stop_and_join() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      stop_.store(true);
    }
    wake_.notify_all();
    for (auto& t : workers_)
      if (t.joinable()) t.join();
  }
  void work(int worker) {
    for (;;) {
      const std::size_t i = next_.fetch_add(1);
      if (i >= count_) return;
      try {
        (*job_)(i, worker);
      } catch (...) {
        std::lock_guard<std::mutex> lock(mutex_);
        if (!error_) error_ = std::current_exception();
        next_.store(count_);  // stop handing out work
      }
    }
  }
  void worker_loop(int worker) {
    std::size_t seen = 0;
    for (;;) {
      const auto fresh = [&] { return stop_.load() || generation_.load(std::memory_order_acquire) != seen; };
      if (!spin_until(fresh)) {
        std::unique_lock<std::mutex> lock(mutex_);
        wake_.wait(lock, fresh);
      }
      if (stop_.load()) return;
      // The job's fields were written before the generation (release / acquire).
      seen = generation_.load(std::memory_order_acquire);
      work(worker);
      if (active_.fetch_sub(1, std::memory_order_acq_rel) == 1) {
        std::lock_guard<std::mutex> lock(mutex_);  // the caller may be about to wait
        done_.notify_one();
      }
    }
  }

  int threads_;
  std::vector<std::thread> workers_;
  std::mutex mutex_, busy_;
  std::condition_variable wake_, done_;
  const std::function<void(std::size_t, int)>* job_ = nullptr;
  std::size_t count_ = 0;
  std::atomic<std::size_t> generation_{0};
  std::atomic<std::size_t> next_{0};
  std::atomic<int> active_{0};
  std::atomic<bool> stop_{false};
  std::exception_ptr error_;
};

// A process-wide pool per thread count, created on first use.
inline ThreadPool& shared_pool(int threads) {
  static std::mutex mutex;
  static std::vector<std::unique_ptr<ThreadPool>> pools;
  std::lock_guard<std::mutex> lock(mutex);
  for (auto& p : pools)
    if (p->size() == threads) return *p;
  pools.push_back(std::make_unique<ThreadPool>(threads));
  return *pools.back();
}

// parallel_for(n, threads, fn): fn(i, worker) for i in [0, n) on `threads`
// threads (0 = default). worker < threads indexes per-thread scratch space.
template <class F>
void parallel_for(std::size_t n, int threads, F&& fn) {
  threads = resolve_threads(threads);
  if (threads == 1 || n <= 1) {
    for (std::size_t i = 0; i < n; ++i) fn(i, 0);
    return;
  }
  const std::function<void(std::size_t, int)> job = [&fn](std::size_t i, int w) { fn(i, w); };
  shared_pool(threads).run(n, job);
}

}  // namespace orbitforge
