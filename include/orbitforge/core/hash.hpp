#pragma once
// FNV-1a, 64 bit: a small, dependency-free content hash for cache keys and file
// records (not a cryptographic hash: it detects damage and changed inputs, not
// tampering).
#include <cstddef>
#include <cstdint>
#include <sstream>
#include <string>
#include <string_view>

namespace orbitforge {

inline constexpr std::uint64_t kFnv1aSeed = 1469598103934665603ull;

inline std::uint64_t fnv1a(const void* data, std::size_t n, std::uint64_t h = kFnv1aSeed) {
  const auto* p = static_cast<const unsigned char*>(data);
  for (std::size_t i = 0; i < n; ++i) {
    h ^= p[i];
    h *= 1099511628211ull;
  }
  return h;
}
inline std::uint64_t fnv1a(std::string_view s, std::uint64_t h = kFnv1aSeed) { return fnv1a(s.data(), s.size(), h); }
inline std::uint64_t fnv1a(const std::string& s, std::uint64_t h = kFnv1aSeed) {
  return fnv1a(s.data(), s.size(), h);
}
inline std::uint64_t fnv1a(const char* s, std::uint64_t h = kFnv1aSeed) { return fnv1a(std::string_view(s), h); }

inline std::string hex64(std::uint64_t h) {
  std::ostringstream os;
  os << std::hex << h;
  return os.str();
}

}  // namespace orbitforge
