// libFuzzer target: COLMAP binary parsers from memory. The input is parsed as
// each of cameras.bin, images.bin and points3D.bin; also, the first two bytes
// (little-endian length n) split the rest into cameras.bin (n bytes) and
// images.bin, turned into frame cameras when both parse. orbitforge::Error is
// expected for bad input; anything else is a bug.
#include <cstdint>
#include <cstdlib>
#include <string>
#include <string_view>

#include "orbitforge/io/colmap.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace orbitforge;
  const std::string_view bytes(reinterpret_cast<const char*>(data), size);
  const std::string name = "fuzz.bin";
  try {
    parse_colmap_cameras_binary(bytes, name);
  } catch (const Error&) {
  }
  try {
    parse_colmap_images_binary(bytes, name);
  } catch (const Error&) {
  }
  try {
    parse_colmap_points3D_binary(bytes, name);
  } catch (const Error&) {
  }
  if (size < 2) return 0;
  const std::size_t n = std::size_t(data[0]) | (std::size_t(data[1]) << 8);
  if (n > size - 2) return 0;
  try {
    ColmapModel m;
    m.cameras = parse_colmap_cameras_binary(bytes.substr(2, n), "cameras.bin");
    m.images = parse_colmap_images_binary(bytes.substr(2 + n), "images.bin");
    check_colmap_model(m, "images.bin");
    for (const auto& f : colmap_frame_cameras<float>(m))
      if (!f.camera.is_finite()) std::abort();
    for (const auto& f : colmap_frame_cameras<double>(m))
      if (!f.camera.is_finite()) std::abort();
  } catch (const Error&) {
  }
  return 0;
}
