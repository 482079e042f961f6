#pragma once
// Minimal binary (de)serialisation helpers for checkpoints: native-endian PODs and
// arrays, with a tagged header so that a wrong or truncated file fails loudly.
#include <algorithm>
#include <cstdint>
#include <cstring>
#include <istream>
#include <ostream>
#include <string>
#include <string_view>
#include <type_traits>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/core/hash.hpp"

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
  // Grown as the data arrives (1 MiB at a time), so that a damaged length fails
  // as a truncated stream instead of allocating up to 2^36 values up front.
  constexpr std::uint64_t chunk = std::max<std::uint64_t>(1, (std::uint64_t(1) << 20) / sizeof(T));
  std::vector<T> v;
  while (v.size() < n) {
    const std::size_t done = v.size(), k = std::size_t(std::min<std::uint64_t>(n - done, chunk));
    v.resize(done + k);
    is.read(reinterpret_cast<char*>(v.data() + done), std::streamsize(k * sizeof(T)));
    ensure(bool(is), "binary_io: truncated stream while reading ", what);
  }
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

// Files (as opposed to streams) end in a checksum trailer: "OFCKSUM1", the
// payload's size and its FNV-1a hash (u64 each, native order), 24 bytes. A file
// cut short, extended or with damaged bytes is then refused as a whole instead of
// being parsed into plausible but wrong values (0xFF bytes in a float array read
// as NaN, not as an error).
inline constexpr char kChecksumTag[9] = "OFCKSUM1";
inline constexpr std::size_t kChecksumTrailerBytes = 24;

inline void append_checksum(std::string& bytes) {
  // As a string_view: fnv1a(char*, n) would pick the C-string overload (n as the seed).
  const std::uint64_t size = bytes.size(), hash = fnv1a(std::string_view(bytes));
  bytes.append(kChecksumTag, 8);
  bytes.append(reinterpret_cast<const char*>(&size), 8);
  bytes.append(reinterpret_cast<const char*>(&hash), 8);
}

// The payload of `bytes` after checking its trailer; Error saying what is wrong otherwise.
inline std::string checked_payload(const std::string& bytes) {
  const std::size_t n = bytes.size();
  ensure(n >= kChecksumTrailerBytes && bytes.compare(n - kChecksumTrailerBytes, 8, kChecksumTag, 8) == 0,
         "no checksum trailer at the end of its ", n,
         " bytes (cut short, overwritten, or written before checkpoints carried a checksum)");
  std::uint64_t size = 0, hash = 0;
  std::memcpy(&size, bytes.data() + n - 16, 8);
  std::memcpy(&hash, bytes.data() + n - 8, 8);
  const std::size_t payload = n - kChecksumTrailerBytes;
  ensure(size == payload, "the checksum trailer records ", size, " bytes of data, the file holds ", payload);
  const std::uint64_t actual = fnv1a(std::string_view(bytes.data(), payload));
  ensure(actual == hash, "checksum mismatch (FNV-1a ", hex64(actual), ", recorded ", hex64(hash),
         "): the data is damaged");
  return bytes.substr(0, payload);
}

}  // namespace binary_io
}  // namespace orbitforge
