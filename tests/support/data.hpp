#pragma once
// Access to the recorded inputs in ../shared/data. A fresh clone has none, so
// tests that need them skip with a message; under CI (CI=true) they must not
// skip, and a missing folder fails the test instead.
#include <catch2/catch.hpp>

#include <cctype>
#include <cstdlib>
#include <filesystem>
#include <string>

namespace orbitforge_test {

inline bool running_in_ci() {
  // CI services set CI to "true", "1", "yes" ...: anything but empty, 0 or false.
  const char* ci = std::getenv("CI");
  if (ci == nullptr) return false;
  std::string v(ci);
  for (char& c : v) c = char(std::tolower(static_cast<unsigned char>(c)));
  return !v.empty() && v != "0" && v != "false" && v != "no";
}

inline std::filesystem::path shared_data_dir() {
  if (const char* env = std::getenv("ORBITFORGE_SHARED_DATA")) return env;
  return ORBITFORGE_SHARED_DATA_DIR;
}

// Returns true when `relative` exists under shared/data. Otherwise: in CI the
// test fails; elsewhere it prints why it skips and returns false.
inline bool have_shared_data(const std::string& relative) {
  const auto path = shared_data_dir() / relative;
  if (std::filesystem::exists(path)) return true;
  if (running_in_ci()) {
    FAIL("shared data missing in CI: " << path.string());
  }
  WARN("SKIPPED: shared data not found at " << path.string()
                                            << " (set ORBITFORGE_SHARED_DATA or place shared/ beside the checkout)");
  return false;
}

inline std::string shared_path(const std::string& relative) { return (shared_data_dir() / relative).string(); }

}  // namespace orbitforge_test
