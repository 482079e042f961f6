#pragma once
// A fresh folder under the system's temporary directory, removed with its
// contents when the object goes out of scope.
#include <filesystem>
#include <random>
#include <string>
#include <system_error>

namespace orbitforge_test {

struct TempDir {
  std::filesystem::path root;
  explicit TempDir(const std::string& prefix) {
    std::random_device rd;
    root = std::filesystem::temp_directory_path() / ("orbitforge_" + prefix + "_" + std::to_string(rd()));
    std::filesystem::create_directories(root);
  }
  ~TempDir() {
    std::error_code ec;
    std::filesystem::remove_all(root, ec);
  }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
};

}  // namespace orbitforge_test
