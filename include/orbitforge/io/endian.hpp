#pragma once
// The host's byte order, for formats that store little-endian data.
#include <cstdint>
#include <cstring>

namespace orbitforge {

inline bool host_is_little_endian() {
  const std::uint16_t one = 1;
  unsigned char b;
  std::memcpy(&b, &one, 1);
  return b == 1;
}

}  // namespace orbitforge
