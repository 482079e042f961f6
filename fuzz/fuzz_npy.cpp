// libFuzzer target: .npy parsing from memory. The input is parsed whole (and
// what parses must survive npy_bytes -> parse_npy unchanged); also the first
// two bytes (little-endian length n) split the rest into an extrinsics file (n
// bytes) and an intrinsics file for npy_cameras. orbitforge::Error is expected
// for bad input; anything else is a bug.
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <string>
#include <string_view>

#include "orbitforge/io/npy.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace orbitforge;
  const std::string_view bytes(reinterpret_cast<const char*>(data), size);
  try {
    const NpyArray a = parse_npy(bytes, "fuzz.npy");
    const NpyArray b = parse_npy(npy_bytes(a.shape, a.data, "fuzz.npy"), "fuzz.npy");
    if (a.shape != b.shape || a.data.size() != b.data.size()) std::abort();
    if (!a.data.empty() && std::memcmp(a.data.data(), b.data.data(), a.data.size() * sizeof(double)) != 0) std::abort();
  } catch (const Error&) {
  }
  if (size < 2) return 0;
  const std::size_t n = std::size_t(data[0]) | (std::size_t(data[1]) << 8);
  if (n > size - 2) return 0;
  try {
    const NpyArray e = parse_npy(bytes.substr(2, n), "extri.npy");
    const NpyArray k = parse_npy(bytes.substr(2 + n), "intri.npy");
    for (const auto& f : npy_cameras<float>(e, "extri.npy", k, "intri.npy", 64, 48))
      if (!f.camera.is_finite()) std::abort();
    for (const auto& f : npy_cameras<double>(e, "extri.npy", k, "intri.npy", 64, 48))
      if (!f.camera.is_finite()) std::abort();
  } catch (const Error&) {
  }
  return 0;
}
