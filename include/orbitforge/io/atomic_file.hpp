#pragma once
// Whole-file reads and crash-safe writes. A write goes to a temporary name in
// the destination's directory and is renamed over the destination, so a reader
// never sees a half-written file (rename within one directory is atomic on POSIX).
#include <atomic>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <sstream>
#include <string>
#include <system_error>
#include <thread>

#include "orbitforge/core/error.hpp"
#include "orbitforge/core/limits.hpp"

namespace orbitforge {

namespace detail {
// A name unlikely to collide with a concurrent writer (other thread or process).
inline std::string unique_temp_suffix() {
  static std::atomic<unsigned long long> counter{0};
  std::ostringstream os;
  os << ".tmp." << std::hex
     << std::chrono::steady_clock::now().time_since_epoch().count() << '.'
     << std::hash<std::thread::id>{}(std::this_thread::get_id()) << '.' << counter.fetch_add(1);
  return os.str();
}
}  // namespace detail

inline void write_file_atomic(const std::string& path, const std::string& bytes) {
  namespace fs = std::filesystem;
  ensure(!path.empty(), "write_file_atomic: empty path");
  const fs::path target(path);
  const std::string temp = path + detail::unique_temp_suffix();
  {
    std::ofstream out(temp, std::ios::binary | std::ios::trunc);
    ensure(out.is_open(), path, ": cannot open temporary file ", temp, " for writing");
    out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
    out.close();
    if (out.fail()) {
      std::error_code ignored;
      fs::remove(temp, ignored);
      fail(path, ": write failed (", bytes.size(), " bytes to ", temp, ")");
    }
  }
  std::error_code ec;
  fs::rename(temp, target, ec);
  if (ec) {
    std::error_code ignored;
    fs::remove(temp, ignored);
    fail(path, ": cannot rename temporary file into place: ", ec.message());
  }
}

inline std::string read_file_bytes(const std::string& path) {
  namespace fs = std::filesystem;
  std::error_code ec;
  ensure(fs::exists(path, ec), path, ": file does not exist");
  ensure(!fs::is_directory(path, ec), path, ": is a directory, expected a file");
  std::ifstream in(path, std::ios::binary);
  ensure(in.is_open(), path, ": cannot open for reading");
  const auto size = fs::file_size(path, ec);
  return with_memory_context(
      [&] {
        std::ostringstream os;
        os << in.rdbuf();
        ensure(!in.bad(), path, ": read error");
        return os.str();
      },
      ec ? 0 : std::uint64_t(size), "reading ", path);
}

}  // namespace orbitforge
