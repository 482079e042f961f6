#pragma once
// Minimal binary (de)serialisation helpers for checkpoints: native-endian PODs and
// arrays, with a tagged header so that a wrong or truncated file fails loudly.
#include <cstdint>
#include <istream>
#include <ostream>
#include <string>
#include <type_traits>
#include <vector>

#include "orbitforge/core/error.hpp"

namespace orbitforge {
namespace binary_io {

template <class T>
void write(std::ostream& os, const T& v) {
  static_assert(std::is_trivially_copyable<T>::value, "binary_io::write: POD only");
  os.write(reinterpret_cast<const char*>(&v), sizeof(T));
}

template <class T>
T read(std::istream& is, const char* what) {
  static_assert(std::is_trivially_copyable<T>::value, "binary_io::read: POD only");
  T v{};
  is.read(reinterpret_cast<char*>(&v), sizeof(T));
  ensure(bool(is), "binary_io: truncated stream while reading ", what);
  return v;
}

template <class T>
void write_array(std::ostream& os, const T* data, std::uint64_t n) {
  write<std::uint64_t>(os, n);
  if (n) os.write(reinterpret_cast<const char*>(data), std::streamsize(n * sizeof(T)));
}

template <class T>
std::vector<T> read_array(std::istream& is, const char* what, std::uint64_t max_count = (std::uint64_t(1) << 36)) {
  const auto n = read<std::uint64_t>(is, what);
  ensure(n <= max_count, "binary_io: implausible length ", n, " for ", what);
  std::vector<T> v(n);
  if (n) is.read(reinterpret_cast<char*>(v.data()), std::streamsize(n * sizeof(T)));
  ensure(bool(is), "binary_io: truncated stream while reading ", what);
  return v;
}

inline void write_string(std::ostream& os, const std::string& s) { write_array(os, s.data(), s.size()); }
inline std::string read_string(std::istream& is, const char* what) {
  const auto v = read_array<char>(is, what, 1 << 20);
  return std::string(v.begin(), v.end());
}

// An 8-byte tag plus the scalar size, checked on read.
inline void write_tag(std::ostream& os, const char (&tag)[9], std::uint32_t scalar_bytes) {
  os.write(tag, 8);
  write<std::uint32_t>(os, scalar_bytes);
}
inline void read_tag(std::istream& is, const char (&tag)[9], std::uint32_t scalar_bytes) {
  char got[8] = {};
  is.read(got, 8);
  ensure(bool(is) && std::string(got, 8) == std::string(tag, 8), "binary_io: expected a '", std::string(tag, 8),
         "' record, found something else");
  const auto sb = read<std::uint32_t>(is, tag);
  ensure(sb == scalar_bytes, "binary_io: '", std::string(tag, 8), "' record holds ", sb,
         "-byte scalars, this build reads ", scalar_bytes, "-byte scalars");
}

}  // namespace binary_io
}  // namespace orbitforge
