// libFuzzer target: transforms.json parsing from memory, in float and double.
// What parses must be finite and must survive a write/parse round trip.
// orbitforge::Error is expected for bad input; anything else is a bug
// (nlohmann exceptions must have been turned into orbitforge::Error).
#include <cstdint>
#include <cstdlib>
#include <string>

#include "orbitforge/io/transforms_json.hpp"

namespace {
template <class S>
void run(const std::string& text) {
  using namespace orbitforge;
  std::vector<FrameCamera<S>> cams;
  try {
    cams = parse_transforms_json<S>(text, "fuzz.json");
  } catch (const Error&) {
    return;
  }
  for (const auto& f : cams)
    if (!f.camera.is_finite()) std::abort();
  // Our own output must read back, with the same number of frames.
  try {
    const auto again = parse_transforms_json<S>(transforms_json_text(cams, "fuzz.json"), "fuzz.json");
    if (again.size() != cams.size()) std::abort();
  } catch (const Error&) {
    std::abort();
  }
}
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  run<float>(text);
  run<double>(text);
  return 0;
}
