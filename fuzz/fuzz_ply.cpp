// libFuzzer target for the PLY reader: any byte string must either parse into a
// consistent scene or throw orbitforge::Error (never crash, hang, leak or allocate
// more than the input can justify).
//   build/fuzz/fuzz_ply -max_total_time=300 -rss_limit_mb=2048 CORPUS_DIR
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "orbitforge/io/ply.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string bytes(reinterpret_cast<const char*>(data), size);
  try {
    std::vector<std::string> warnings;  // trailing data: a warning, kept off stderr
    const auto scene = orbitforge::read_ply_from_memory<float>(bytes, "fuzz.ply", &warnings);
    scene.check_consistent();
    // What was read must also write and read back to the same size.
    const auto again = orbitforge::read_ply_from_memory<float>(orbitforge::ply_bytes(scene), "again.ply");
    if (again.size() != scene.size() || again.sh_degree != scene.sh_degree) __builtin_trap();
  } catch (const orbitforge::Error&) {
  }
  return 0;
}
