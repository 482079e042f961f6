#include <catch2/catch.hpp>

#include <atomic>
#include <chrono>
#include <cstdlib>
#include <fstream>
#include <functional>
#include <future>
#include <string>
#include <thread>

#include "orbitforge/core/limits.hpp"
#include "orbitforge/core/parallel_for.hpp"

#if defined(__linux__)
#include <sys/resource.h>
#endif

#include "support/sanitizer.hpp"  // ORBITFORGE_TEST_SANITIZED

using namespace orbitforge;

namespace {

bool mentions(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

std::string error_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

#if defined(__linux__)
// Virtual memory the process maps now (VmSize), in bytes; 0 when unknown.
std::uint64_t mapped_bytes() {
  std::ifstream in("/proc/self/status");
  std::string key;
  while (in >> key) {
    if (key == "VmSize:") {
      std::uint64_t kb = 0;
      in >> kb;
      return kb * 1024;
    }
    std::getline(in, key);
  }
  return 0;
}
#endif

}  // namespace

TEST_CASE("limits: amounts, environment variables and scoped overrides", "[core][limits]") {
  std::uint64_t v = 0;
  REQUIRE(limits_detail::parse_amount("123", false, v));
  REQUIRE(v == 123);
  REQUIRE(limits_detail::parse_amount("8G", true, v));
  REQUIRE(v == (std::uint64_t(8) << 30));
  REQUIRE(limits_detail::parse_amount("64m", true, v));
  REQUIRE(v == (std::uint64_t(64) << 20));
  REQUIRE_FALSE(limits_detail::parse_amount("8G", false, v));
  REQUIRE_FALSE(limits_detail::parse_amount("0", true, v));
  REQUIRE_FALSE(limits_detail::parse_amount("-3", true, v));
  REQUIRE_FALSE(limits_detail::parse_amount("12x", true, v));
  REQUIRE_FALSE(limits_detail::parse_amount("99999999999999999999", false, v));
  REQUIRE_FALSE(limits_detail::parse_amount("20000000T", true, v));  // overflows 64 bits

  const Limits d = Limits::defaults();
  REQUIRE(d.max_threads == 256);
  REQUIRE(d.max_image_pixels == (std::uint64_t(1) << 28));
  REQUIRE(d.max_memory_bytes > 0);

  ::setenv("ORBITFORGE_MAX_THREADS", "12", 1);
  ::setenv("ORBITFORGE_MAX_MEMORY_BYTES", "3G", 1);
  const Limits e = Limits::from_environment();
  CHECK(e.max_threads == 12);
  CHECK(e.max_memory_bytes == (std::uint64_t(3) << 30));
  CHECK(e.max_image_pixels == d.max_image_pixels);
  ::setenv("ORBITFORGE_MAX_THREADS", "lots", 1);
  const std::string bad = error_of([] { Limits::from_environment(); });
  CHECK(mentions(bad, "ORBITFORGE_MAX_THREADS='lots'"));
  ::unsetenv("ORBITFORGE_MAX_THREADS");
  ::unsetenv("ORBITFORGE_MAX_MEMORY_BYTES");

  const Limits before = limits();
  {
    Limits l = before;
    l.max_threads = 3;
    ScopedLimits scope(l);
    REQUIRE(limits().max_threads == 3);
  }
  REQUIRE(limits().max_threads == before.max_threads);
  Limits zero = before;
  zero.max_threads = 0;
  REQUIRE_THROWS_AS(set_limits(zero), Error);
  REQUIRE(format_bytes(512) == "512 bytes");
  REQUIRE(format_bytes(std::uint64_t(3) << 29) == "1.5 GiB");
}

TEST_CASE("thread counts over Limits::max_threads are refused with the limit named", "[core][limits][parallel]") {
  Limits l = limits();
  l.max_threads = 4;
  ScopedLimits scope(l);
  const std::string pool = error_of([] { ThreadPool p(5); });
  CHECK(mentions(pool, "ThreadPool: 5 threads requested, over the limit of 4"));
  CHECK(mentions(pool, "Limits::max_threads"));
  const std::string pf = error_of([] { parallel_for(10, 9, [](std::size_t, int) {}); });
  CHECK(mentions(pf, "9 threads requested, over the limit of 4"));
  CHECK(error_of([] { ThreadPool p(4); }).empty());
  // The default (0) is clamped to the limit, never refused.
  l.max_threads = 1;
  set_limits(l);
  CHECK(resolve_threads(0) == 1);
  CHECK(resolve_threads(1) == 1);
}

// A thread that cannot start (here: no address space left for its stack) must
// make the constructor join the ones already running and throw; before, the
// started workers kept waiting on a condition variable being destroyed and the
// program hung without a message.
TEST_CASE("ThreadPool: a thread that cannot start gives an Error, not a hang", "[core][limits][parallel]") {
#if !defined(__linux__) || defined(ORBITFORGE_TEST_SANITIZED)
  SUCCEED("needs Linux RLIMIT_AS without a sanitizer's shadow memory");
#else
  const std::uint64_t mapped = mapped_bytes();
  REQUIRE(mapped > 0);
  struct rlimit saved;
  REQUIRE(getrlimit(RLIMIT_AS, &saved) == 0);
  std::promise<std::string> result;
  auto done = result.get_future();
  // The pool is built on its own thread so that a hang shows as a failed wait here.
  std::thread builder([&] {
    struct rlimit tight = saved;
    tight.rlim_cur = rlim_t(mapped + (std::uint64_t(48) << 20));  // room for a few 8 MiB stacks, not 64
    if (saved.rlim_cur != RLIM_INFINITY && saved.rlim_cur < tight.rlim_cur) tight.rlim_cur = saved.rlim_cur;
    setrlimit(RLIMIT_AS, &tight);
    std::string message = "constructed";
    try {
      ThreadPool pool(64);
    } catch (const Error& e) {
      message = e.what();
    } catch (const std::exception& e) {
      message = std::string("not an orbitforge::Error: ") + e.what();
    }
    setrlimit(RLIMIT_AS, &saved);
    result.set_value(message);
  });
  if (done.wait_for(std::chrono::seconds(60)) != std::future_status::ready) {
    setrlimit(RLIMIT_AS, &saved);
    FAIL_CHECK("ThreadPool construction hung after a thread failed to start");
    std::_Exit(1);  // the builder thread cannot be joined
  }
  builder.join();
  const std::string message = done.get();
  INFO(message);
  CHECK(mentions(message, "ThreadPool: could not start thread "));
  CHECK(mentions(message, " of 64: "));
  // The pool still works at a size the process can afford.
  std::atomic<int> sum{0};
  ThreadPool small(2);
  small.run(100, [&](std::size_t i, int) { sum += int(i); });
  CHECK(sum.load() == 4950);
#endif
}

TEST_CASE("with_memory_context turns std::bad_alloc into OutOfMemory naming the request", "[core][limits]") {
  try {
    with_memory_context([]() -> int { throw std::bad_alloc(); }, std::uint64_t(3) << 30, "reading ", "x.bin");
    FAIL("no exception");
  } catch (const OutOfMemory& e) {
    CHECK(std::string(e.what()) == "out of memory while reading x.bin (about 3.0 GiB requested)");
    CHECK(e.bytes() == (std::uint64_t(3) << 30));
  }
  // Other errors and results pass through unchanged.
  CHECK(with_memory_context([] { return 7; }, 1, "nothing") == 7);
  CHECK_THROWS_WITH(with_memory_context([]() -> int { fail("bad input"); }, 1, "x"), "bad input");
}
