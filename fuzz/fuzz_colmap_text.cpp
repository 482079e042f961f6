// libFuzzer target: COLMAP text parsers from memory. The input is parsed as
// each of cameras.txt, images.txt and points3D.txt; it is also split at "%%\n"
// into (cameras, images, points) and, when those parse, turned into frame
// cameras. orbitforge::Error is the expected outcome for bad input; anything
// else (crash, sanitizer report, other exception) is a bug.
#include <cstdint>
#include <cstdlib>
#include <string>
#include <string_view>

#include "orbitforge/io/colmap.hpp"

namespace {
template <class S>
void check_frames(const orbitforge::ColmapModel& m) {
  const auto cams = orbitforge::colmap_frame_cameras<S>(m);
  for (const auto& f : cams)
    if (!f.camera.is_finite()) std::abort();  // never NaN, even for invalid frames
}
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace orbitforge;
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  const std::string name = "fuzz.txt";
  try {
    parse_colmap_cameras_text(text, name);
  } catch (const Error&) {
  }
  try {
    parse_colmap_images_text(text, name);
  } catch (const Error&) {
  }
  try {
    parse_colmap_points3D_text(text, name);
  } catch (const Error&) {
  }
  try {
    const std::size_t a = text.find("%%\n");
    if (a == std::string_view::npos) return 0;
    const std::size_t b = text.find("%%\n", a + 3);
    ColmapModel m;
    m.cameras = parse_colmap_cameras_text(text.substr(0, a), "cameras.txt");
    m.images = parse_colmap_images_text(text.substr(a + 3, b == std::string_view::npos ? std::string_view::npos : b - a - 3),
                                        "images.txt");
    if (b != std::string_view::npos) m.points = parse_colmap_points3D_text(text.substr(b + 3), "points3D.txt");
    check_colmap_model(m, "images.txt");
    check_frames<float>(m);
    check_frames<double>(m);
  } catch (const Error&) {
  }
  return 0;
}
