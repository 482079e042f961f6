#pragma once
// Seeding for targets that generate their own corpus: the corpus folders named on
// libFuzzer's command line that are missing or empty (flags are skipped).
#include <filesystem>
#include <string>
#include <system_error>
#include <vector>

inline std::vector<std::string> empty_corpus_dirs(int argc, char** argv) {
  std::vector<std::string> dirs;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg.empty() || arg[0] == '-') continue;
    std::error_code ec;
    namespace fs = std::filesystem;
    if (!fs::exists(arg, ec) || (fs::is_directory(arg, ec) && fs::is_empty(arg, ec))) dirs.push_back(arg);
  }
  return dirs;
}
