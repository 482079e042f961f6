#pragma once
// Small command-line helpers shared by the example programs: strict number
// parsing, r,g,b triples, and one convention for exit codes (2 = bad arguments,
// 1 = bad input or failure, 0 = success), with messages on stderr.
#include <array>
#include <cmath>
#include <exception>
#include <functional>
#include <iostream>
#include <stdexcept>
#include <new>
#include <string>

#include "orbitforge/core/limits.hpp"

namespace orbitforge::cli {

// Bad command-line arguments (exit status 2).
struct UsageError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

inline long parse_int(const std::string& program, const std::string& flag, const std::string& text,
                      long lo = -2147483647L, long hi = 2147483647L) {
  std::size_t used = 0;
  long x = 0;
  try {
    x = std::stol(text, &used);
  } catch (...) {
    used = 0;
  }
  if (text.empty() || used != text.size() || x < lo || x > hi)
    throw UsageError(program + ": " + flag + " expects an integer in [" + std::to_string(lo) + ", " +
                     std::to_string(hi) + "], got '" + text + "'");
  return x;
}

inline double parse_double(const std::string& program, const std::string& flag, const std::string& text) {
  std::size_t used = 0;
  double x = 0;
  try {
    x = std::stod(text, &used);
  } catch (...) {
    used = 0;
  }
  if (text.empty() || used != text.size() || !std::isfinite(x))
    throw UsageError(program + ": " + flag + " expects a number, got '" + text + "'");
  return x;
}

// --threads N: 0 (all hardware threads) up to orbitforge::Limits::max_threads.
inline int parse_threads(const std::string& program, const std::string& flag, const std::string& text) {
  const long n = parse_int(program, flag, text, 0);
  const int max = limits().max_threads;
  if (n > max)
    throw UsageError(program + ": " + flag + " " + text + " is over the thread limit of " + std::to_string(max) +
                     " (orbitforge::Limits::max_threads; the environment variable ORBITFORGE_MAX_THREADS raises it)");
  return int(n);
}

// "r,g,b" with each value in [0, 1].
inline std::array<double, 3> parse_rgb(const std::string& program, const std::string& flag, const std::string& text) {
  std::array<double, 3> c{};
  std::size_t pos = 0;
  for (int k = 0; k < 3; ++k) {
    const std::size_t comma = k < 2 ? text.find(',', pos) : std::string::npos;
    if (k < 2 && comma == std::string::npos)
      throw UsageError(program + ": " + flag + " expects r,g,b in [0,1], got '" + text + "'");
    c[std::size_t(k)] = parse_double(program, flag, text.substr(pos, k < 2 ? comma - pos : std::string::npos));
    if (c[std::size_t(k)] < 0 || c[std::size_t(k)] > 1)
      throw UsageError(program + ": " + flag + " values must lie in [0,1], got '" + text + "'");
    pos = comma + 1;
  }
  return c;
}

// Walks argv: `flag()` is the current argument, `value()` consumes the next one.
class ArgWalker {
 public:
  ArgWalker(std::string program, int argc, char** argv) : program_(std::move(program)), argc_(argc), argv_(argv) {}
  bool next() { return ++i_ < argc_; }
  std::string flag() const { return argv_[i_]; }
  std::string value() {
    if (i_ + 1 >= argc_) throw UsageError(program_ + ": " + flag() + " needs a value");
    return argv_[++i_];
  }
  [[noreturn]] void unknown() const { throw UsageError(program_ + ": unknown argument '" + flag() + "'"); }

 private:
  std::string program_;
  int argc_, i_ = 0;
  char** argv_;
};

// The message of an exception that reaches a program's top level. The library
// turns the allocations it can describe into orbitforge::OutOfMemory ("out of
// memory while rendering a 30000x30000 frame ... (about 28.5 GiB requested)"); a
// bare std::bad_alloc from anywhere else still says what it means.
inline std::string describe(const std::exception& e) {
  if (dynamic_cast<const std::bad_alloc*>(&e))
    return std::string("out of memory (") + e.what() + " from an allocation the library does not describe)";
  return e.what();
}

// Runs a program body with the exit-code convention above.
inline int run(const std::function<int()>& body) {
  try {
    return body();
  } catch (const UsageError& e) {
    std::cerr << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {
    std::cerr << describe(e) << "\n";
    return 1;
  }
}

}  // namespace orbitforge::cli
