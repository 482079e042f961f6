#pragma once
// Huge pages for a program's heap, where the kernel gives them only on request.
//
// Why: training gathers per-Gaussian arrays in rank order (binning's packing,
// projection's reads of the scene), so its accesses jump across megabytes. With
// 4 KB pages those jumps miss the TLB; with 2 MB pages they do not. Linux hands
// out 2 MB pages to memory that asks for them when
// /sys/kernel/mm/transparent_hugepage/enabled is "madvise" (common on servers and
// cloud images), and glibc 2.35 and later asks for them for its whole heap when
// started with GLIBC_TUNABLES=glibc.malloc.hugetlb=1. Tunables are read only when
// a process starts, so a program that wants them re-executes itself once with the
// tunable added (docs/benchmarks.md, "Huge pages": the paper's budget took
// 0.92-0.97x the time on two videos, with the same result).
//
// relaunch_with_huge_pages(argv) does that as a program's first statement. It does
// nothing where it would not help: transparent huge pages "always" (already
// given) or "never", another OS or C library, a sanitizer build (its allocator is
// not glibc's), GLIBC_TUNABLES already naming the setting (the user's choice), or
// ORBITFORGE_HUGE_PAGES=0 in the environment. Programs the process starts inherit
// the tunable. huge_page_state() says which pages the running process's heap
// gets, for a run's record: its timings depend on it.
#include <cstdlib>
#include <fstream>
#include <optional>
#include <string>

// Where a relaunch can help: glibc 2.35 or later on Linux, and glibc's allocator
// (a sanitizer brings its own).
#if defined(__linux__) && defined(__GLIBC__) && (__GLIBC__ > 2 || (__GLIBC__ == 2 && __GLIBC_MINOR__ >= 35)) && \
    !defined(__SANITIZE_ADDRESS__) && !defined(__SANITIZE_THREAD__)
#define ORBITFORGE_DETAIL_HUGE_PAGE_RELAUNCH 1
#if defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer) || __has_feature(memory_sanitizer)
#undef ORBITFORGE_DETAIL_HUGE_PAGE_RELAUNCH
#define ORBITFORGE_DETAIL_HUGE_PAGE_RELAUNCH 0
#endif
#endif
#else
#define ORBITFORGE_DETAIL_HUGE_PAGE_RELAUNCH 0
#endif

#if ORBITFORGE_DETAIL_HUGE_PAGE_RELAUNCH
#include <unistd.h>
#endif

namespace orbitforge {

// Whether relaunch_with_huge_pages can re-execute on this build and platform.
inline constexpr bool huge_page_relaunch_built = ORBITFORGE_DETAIL_HUGE_PAGE_RELAUNCH != 0;

// The transparent-huge-page mode, as the kernel brackets it in
// /sys/kernel/mm/transparent_hugepage/enabled ("always [madvise] never" ->
// "madvise"); empty when the text has no bracketed word.
inline std::string thp_mode(const std::string& enabled_text) {
  const auto open = enabled_text.find('[');
  const auto close = enabled_text.find(']', open);
  if (open == std::string::npos || close == std::string::npos) return {};
  return enabled_text.substr(open + 1, close - open - 1);
}

// The text of /sys/kernel/mm/transparent_hugepage/enabled, empty where there is none.
inline std::string thp_enabled_text() {
  std::ifstream file("/sys/kernel/mm/transparent_hugepage/enabled");
  std::string text;
  if (file) std::getline(file, text);
  return text;
}

// The value GLIBC_TUNABLES text (null when unset) gives glibc.malloc.hugetlb,
// or nothing where it does not name it.
inline std::optional<std::string> hugetlb_tunable(const char* tunables) {
  if (tunables == nullptr) return std::nullopt;
  const std::string t(tunables), key = "glibc.malloc.hugetlb=";
  const auto at = t.find(key);
  if (at == std::string::npos) return std::nullopt;
  const auto end = t.find(':', at);
  return t.substr(at + key.size(), end == std::string::npos ? std::string::npos : end - at - key.size());
}

// The GLIBC_TUNABLES value to relaunch with, or nothing when a relaunch would not
// help or is not wanted. `tunables` is the current value (null when unset),
// `opt_out` the ORBITFORGE_HUGE_PAGES value (null when unset; "0" refuses).
inline std::optional<std::string> huge_page_tunables(const std::string& thp_enabled_text, const char* tunables,
                                                     const char* opt_out) {
  if (opt_out != nullptr && std::string(opt_out) == "0") return std::nullopt;
  if (thp_mode(thp_enabled_text) != "madvise") return std::nullopt;
  if (hugetlb_tunable(tunables)) return std::nullopt;
  const std::string current = tunables == nullptr ? std::string() : std::string(tunables);
  return current.empty() ? std::string("glibc.malloc.hugetlb=1") : current + ":glibc.malloc.hugetlb=1";
}

// Which pages a process's heap gets, in words, from the kernel's mode text and
// the process's GLIBC_TUNABLES (null when unset): "2 MB pages ..." or "4 KB
// pages ...", then why in brackets, or "unknown ..." where the kernel does not say.
inline std::string huge_page_state(const std::string& thp_enabled_text, const char* tunables) {
  const std::string mode = thp_mode(thp_enabled_text);
  if (mode.empty()) return "unknown (no transparent huge page mode)";
  if (mode == "always") return "2 MB pages (transparent huge pages: always)";
  if (mode != "madvise") return "4 KB pages (transparent huge pages: " + mode + ")";
  const auto value = hugetlb_tunable(tunables);
  if (huge_page_relaunch_built && value && !value->empty() && *value != "0")
    return "2 MB pages on request (transparent huge pages: madvise; glibc.malloc.hugetlb=" + *value + ")";
  return "4 KB pages (transparent huge pages: madvise; not requested)";
}

// huge_page_state for the running process.
inline std::string huge_page_state() { return huge_page_state(thp_enabled_text(), std::getenv("GLIBC_TUNABLES")); }

// Re-executes the running program with glibc's huge-page tunable where that helps
// (see above); returns when it does not, or when the re-execution fails (the
// program then runs as it would have).
inline void relaunch_with_huge_pages(char** argv) {
#if ORBITFORGE_DETAIL_HUGE_PAGE_RELAUNCH
  const std::string text = thp_enabled_text();
  if (text.empty()) return;
  const char* before = std::getenv("GLIBC_TUNABLES");
  const std::optional<std::string> saved = before ? std::optional<std::string>(before) : std::nullopt;
  const auto value = huge_page_tunables(text, before, std::getenv("ORBITFORGE_HUGE_PAGES"));
  if (!value || argv == nullptr || argv[0] == nullptr) return;
  // The executable's own path, not /proc/self/exe, so that ps and top keep its name.
  char path[4096];
  const ssize_t length = readlink("/proc/self/exe", path, sizeof path - 1);
  if (length <= 0 || length >= ssize_t(sizeof path - 1)) return;
  path[length] = '\0';
  if (setenv("GLIBC_TUNABLES", value->c_str(), 1) != 0) return;
  execv(path, argv);
  // Not replaced: carry on as started, leaving the environment as it was.
  if (saved)
    setenv("GLIBC_TUNABLES", saved->c_str(), 1);
  else
    unsetenv("GLIBC_TUNABLES");
#else
  (void)argv;
#endif
}

}  // namespace orbitforge
