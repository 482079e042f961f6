#pragma once
// Resource limits: ceilings checked where a request enters (thread counts, image
// sizes, the memory a frame needs), so that a request the machine cannot serve is
// refused up front with a message naming the limit, instead of deadlocking, being
// killed by the kernel or ending in a bare std::bad_alloc.
//
//   Limits::          default                              environment variable
//   max_threads       256                                  ORBITFORGE_MAX_THREADS
//   max_image_pixels  2^28 = 268435456 (16384 x 16384)     ORBITFORGE_MAX_IMAGE_PIXELS
//   max_memory_bytes  half of the smallest of physical     ORBITFORGE_MAX_MEMORY_BYTES
//                     memory, the cgroup's memory.max and  (a number of bytes, or with
//                     RLIMIT_AS (8 GiB where none can be   a K, M, G or T suffix:
//                     read)                                powers of 1024)
//
// limits() is process-wide: the defaults, overridden by the environment variables
// (read on first use), then by set_limits(). max_memory_bytes bounds one request
// (the buffers of one rendered frame, one tile list), not the process.
//
// Where they are checked: max_threads by resolve_threads / ThreadPool (so
// RenderParams::threads, TrainParams::threads and every parallel_for);
// max_image_pixels by Image and Renderer::render; max_memory_bytes by
// Renderer::render (frame buffers and per-tile arrays, before allocating) and
// bin_splats (the tile lists, once their length is known).
#include <algorithm>
#include <atomic>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <new>
#include <sstream>
#include <string>

#include "orbitforge/core/error.hpp"

#if defined(__unix__) || defined(__APPLE__)
#include <sys/resource.h>
#include <unistd.h>
#endif

namespace orbitforge {

struct Limits {
  int max_threads = 256;
  std::uint64_t max_image_pixels = std::uint64_t(1) << 28;
  std::uint64_t max_memory_bytes = std::uint64_t(8) << 30;  // defaults(): half the memory, when it can be read

  static Limits defaults();
  // defaults() with the ORBITFORGE_MAX_* environment variables applied.
  static Limits from_environment();
};

// Bytes as "12.3 GiB" / "456 MiB" / "789 bytes" for messages.
inline std::string format_bytes(std::uint64_t b) {
  const char* units[] = {"bytes", "KiB", "MiB", "GiB", "TiB", "PiB"};
  double v = double(b);
  int u = 0;
  while (v >= 1024 && u < 5) {
    v /= 1024;
    ++u;
  }
  char s[48];
  if (u == 0) std::snprintf(s, sizeof(s), "%llu bytes", static_cast<unsigned long long>(b));
  else std::snprintf(s, sizeof(s), "%.1f %s", v, units[u]);
  return s;
}

// A memory request that failed, with what it was for:
// "out of memory while <what> (<bytes> requested)".
class OutOfMemory : public Error {
 public:
  // `estimate`: bytes is the caller's estimate of the request, not its exact size.
  OutOfMemory(const std::string& what_for, std::uint64_t bytes, bool estimate = false)
      : Error("out of memory while " + what_for + " (" + (estimate ? "about " : "") + format_bytes(bytes) +
              " requested)"),
        bytes_(bytes) {}
  std::uint64_t bytes() const { return bytes_; }

 private:
  std::uint64_t bytes_;
};

namespace limits_detail {

// Physical memory, the cgroup v2 limit and RLIMIT_AS, whichever is smallest (0 = none known).
inline std::uint64_t memory_available() {
  std::uint64_t m = 0;
  auto take = [&m](std::uint64_t v) {
    if (v > 0) m = m == 0 ? v : std::min(m, v);
  };
#if defined(__unix__) || defined(__APPLE__)
  const long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGE_SIZE);
  if (pages > 0 && page > 0) take(std::uint64_t(pages) * std::uint64_t(page));
  struct rlimit rl;
  if (getrlimit(RLIMIT_AS, &rl) == 0 && rl.rlim_cur != RLIM_INFINITY) take(std::uint64_t(rl.rlim_cur));
#endif
  // A container's memory limit is lower than the host's memory it reports.
  std::ifstream cg("/sys/fs/cgroup/memory.max");
  std::string text;
  if (cg >> text && !text.empty() && text.find_first_not_of("0123456789") == std::string::npos)
    take(std::strtoull(text.c_str(), nullptr, 10));
  return m;
}

// "123", "64M", "8G" (powers of 1024 with a suffix); false when malformed or 0.
inline bool parse_amount(const std::string& text, bool suffixes, std::uint64_t& out) {
  std::size_t i = 0;
  std::uint64_t v = 0;
  while (i < text.size() && text[i] >= '0' && text[i] <= '9') {
    const std::uint64_t d = std::uint64_t(text[i] - '0');
    if (v > (UINT64_MAX - d) / 10) return false;
    v = v * 10 + d;
    ++i;
  }
  if (i == 0) return false;
  int shift = 0;
  if (suffixes && i + 1 == text.size()) {
    const char s = char(text[i] & ~0x20);  // upper case
    shift = s == 'K' ? 10 : s == 'M' ? 20 : s == 'G' ? 30 : s == 'T' ? 40 : -1;
    if (shift < 0) return false;
    ++i;
  }
  if (i != text.size() || v == 0 || v > (UINT64_MAX >> shift)) return false;
  out = v << shift;
  return true;
}

inline void validate(const Limits& l) {
  ensure(l.max_threads >= 1, "Limits: max_threads must be at least 1, got ", l.max_threads);
  ensure(l.max_image_pixels >= 1, "Limits: max_image_pixels must be at least 1");
  ensure(l.max_memory_bytes >= 1, "Limits: max_memory_bytes must be at least 1");
}

struct State {
  std::atomic<int> threads;
  std::atomic<std::uint64_t> pixels, memory;
  explicit State(const Limits& l) : threads(l.max_threads), pixels(l.max_image_pixels), memory(l.max_memory_bytes) {}
};

// Initialised on first use (a bad environment variable throws here, and the next
// call tries again).
inline State& state() {
  static State s(Limits::from_environment());
  return s;
}

}  // namespace limits_detail

inline Limits Limits::defaults() {
  Limits l;
  const std::uint64_t avail = limits_detail::memory_available();
  if (avail > 0) l.max_memory_bytes = avail / 2;
  return l;
}

inline Limits Limits::from_environment() {
  Limits l = defaults();
  auto read = [](const char* name, bool suffixes, std::uint64_t max, std::uint64_t& out) {
    const char* v = std::getenv(name);
    if (!v) return;
    std::uint64_t x = 0;
    ensure(limits_detail::parse_amount(v, suffixes, x) && x <= max, name, "='", v, "' is not a positive integer",
           suffixes ? " (optionally with a K, M, G or T suffix)" : "", " up to ", max);
    out = x;
  };
  std::uint64_t threads = std::uint64_t(l.max_threads);
  read("ORBITFORGE_MAX_THREADS", false, 1u << 20, threads);
  l.max_threads = int(threads);
  read("ORBITFORGE_MAX_IMAGE_PIXELS", false, UINT64_MAX, l.max_image_pixels);
  read("ORBITFORGE_MAX_MEMORY_BYTES", true, UINT64_MAX, l.max_memory_bytes);
  return l;
}

// The limits in force.
inline Limits limits() {
  auto& s = limits_detail::state();
  Limits l;
  l.max_threads = s.threads.load(std::memory_order_relaxed);
  l.max_image_pixels = s.pixels.load(std::memory_order_relaxed);
  l.max_memory_bytes = s.memory.load(std::memory_order_relaxed);
  return l;
}

// Replaces the limits in force (all three at once; thread pools already started
// keep their size).
inline void set_limits(const Limits& l) {
  limits_detail::validate(l);
  auto& s = limits_detail::state();
  s.threads.store(l.max_threads, std::memory_order_relaxed);
  s.pixels.store(l.max_image_pixels, std::memory_order_relaxed);
  s.memory.store(l.max_memory_bytes, std::memory_order_relaxed);
}

// Sets limits for a scope and restores the previous ones (tests, one-off jobs).
class ScopedLimits {
 public:
  explicit ScopedLimits(const Limits& l) : saved_(limits()) { set_limits(l); }
  ~ScopedLimits() { set_limits(saved_); }
  ScopedLimits(const ScopedLimits&) = delete;
  ScopedLimits& operator=(const ScopedLimits&) = delete;

 private:
  Limits saved_;
};

// Refuses a thread count over the limit; `what` names where it came from.
inline void check_thread_count(int threads, const char* what) {
  const int max = limits().max_threads;
  ensure(threads <= max, what, ": ", threads, " threads requested, over the limit of ", max,
         " (orbitforge::Limits::max_threads; raise it with set_limits or ORBITFORGE_MAX_THREADS)");
}

// Refuses a width x height image over the pixel limit; `what` names the image.
inline void check_image_size(std::uint64_t width, std::uint64_t height, const char* what) {
  const std::uint64_t max = limits().max_image_pixels;
  ensure(width == 0 || height <= max / width, what, ": a ", width, "x", height, " image (", width * height,
         " pixels) is over the limit of ", max,
         " pixels (orbitforge::Limits::max_image_pixels; raise it with set_limits or ORBITFORGE_MAX_IMAGE_PIXELS)");
}

// Refuses a request of `bytes` over the memory limit; the parts say what it is for.
template <class... Parts>
inline void check_memory_request(std::uint64_t bytes, const Parts&... what) {
  const std::uint64_t max = limits().max_memory_bytes;
  if (bytes <= max) return;
  fail(what..., " needs about ", format_bytes(bytes), ", over the memory limit of ", format_bytes(max),
       " (orbitforge::Limits::max_memory_bytes; raise it with set_limits or ORBITFORGE_MAX_MEMORY_BYTES)");
}

// Runs f(); a std::bad_alloc from it becomes OutOfMemory saying what was being
// allocated and about how much (the parts of the message follow "while ").
template <class F, class... Parts>
decltype(auto) with_memory_context(F&& f, std::uint64_t estimated_bytes, const Parts&... what) {
  try {
    return f();
  } catch (const std::bad_alloc&) {
    std::ostringstream os;
    (os << ... << what);
    throw OutOfMemory(os.str(), estimated_bytes, true);
  }
}

}  // namespace orbitforge
