#pragma once
// Tests that run outside programs (colmap, ffmpeg, bash) skip with a message
// where one is not on PATH, and fail under CI (CI=true), whose setup installs
// them all.
#include <catch2/catch.hpp>

#include <string>
#include <vector>

#include "orbitforge/pipeline/inputs/external_tools.hpp"
#include "support/data.hpp"

namespace orbitforge_test {

// True when every program is on PATH; otherwise fails under CI and skips elsewhere.
inline bool have_programs(const std::vector<std::string>& programs) {
  for (const auto& p : programs)
    if (orbitforge::find_program(p).empty()) {
      if (running_in_ci()) FAIL("program " << p << " missing in CI (scripts/setup.sh installs it)");
      WARN("SKIPPED: the " << p << " program is not on PATH (Debian package " << p << ")");
      return false;
    }
  return true;
}

}  // namespace orbitforge_test
