#pragma once
// One error type for bad input. Messages name the file, the record and the
// problem; `ensure` only formats its message when the check fails.
#include <sstream>
#include <stdexcept>
#include <string>

namespace orbitforge {

class Error : public std::runtime_error {
 public:
  explicit Error(const std::string& what) : std::runtime_error(what) {}
};

template <class... Parts>
[[noreturn]] inline void fail(const Parts&... parts) {
  std::ostringstream os;
  (os << ... << parts);
  throw Error(os.str());
}

template <class... Parts>
inline void ensure(bool condition, const Parts&... parts) {
  if (!condition) fail(parts...);
}

}  // namespace orbitforge
