// libFuzzer target: stage records (pipeline/stage_record.hpp).
//
// Input: byte 0 = flags, byte 1 = n, then n bytes of the output a.bin, then the
// record text. Per input, in a temporary run folder made once per process:
//  1. parse_stage_record(text): what parses has a "key" string and outputs with
//     relative paths, and survives dump -> parse unchanged.
//  2. The text as stages/s.json next to a.bin and sub/b.ply; check_stage for the
//     output lists {}, {a.bin} and {a.bin, sub/b.ply}: a record found current must
//     parse, carry the key, list exactly those outputs (any non-empty list for {})
//     and each listed path must name a regular file whose size and FNV-1a (computed
//     here, independently) are the recorded ones. recorded_seconds must agree.
//  3. The writer: record_stage for a.bin (+ sub/b.ply, + a file whose name comes
//     from the input when flag 4 is set) with seconds from the input; the record
//     must then be current for exactly that key and list, and stop being current
//     when a.bin changes.
// orbitforge::Error is expected for bad input; anything else is a bug (abort).
//
// Seeds: run with an empty or missing corpus folder and records written by
// record_stage are put there first (see LLVMFuzzerInitialize).
#include <sys/stat.h>
#include <unistd.h>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "orbitforge/pipeline/stage_record.hpp"

#include "seed_dirs.hpp"

namespace fs = std::filesystem;
using namespace orbitforge;

namespace {

[[noreturn]] void bug(const std::string& what) {
  std::fprintf(stderr, "fuzz_stage_record: invariant broken: %s\n", what.c_str());
  std::abort();
}

// Removed at exit (libFuzzer ends with exit()); the name outlives static destructors.
char g_run_dir[] = "/tmp/orbitforge-fuzz-stage-XXXXXX";

const std::string& run_dir() {
  static const std::string* dir = [] {
    if (!::mkdtemp(g_run_dir)) bug("mkdtemp failed");
    std::atexit([] {
      std::error_code ec;
      fs::remove_all(g_run_dir, ec);
    });
    return new std::string(g_run_dir);
  }();
  return *dir;
}

void put(const fs::path& p, const std::string& bytes) {
  fs::create_directories(p.parent_path());
  std::ofstream f(p, std::ios::binary | std::ios::trunc);
  f.write(bytes.data(), std::streamsize(bytes.size()));
  if (!f) bug("cannot write " + p.string());
}

// Independent of the library: the file's bytes, or false when it is not a regular file.
bool slurp(const fs::path& p, std::string& bytes) {
  struct stat st;
  if (::stat(p.c_str(), &st) != 0 || !S_ISREG(st.st_mode)) return false;
  std::ifstream f(p, std::ios::binary);
  std::ostringstream os;
  os << f.rdbuf();
  bytes = os.str();
  return true;
}

std::string fnv1a_hex(const std::string& s) {
  std::uint64_t h = 1469598103934665603ull;
  for (unsigned char c : s) {
    h ^= c;
    h *= 1099511628211ull;
  }
  char buf[17];
  std::snprintf(buf, sizeof buf, "%llx", static_cast<unsigned long long>(h));
  return buf;
}

const std::string kB = "ply\nformat binary_little_endian 1.0\nend_header\n";

// A record found current must be one a careful reader accepts for these outputs.
void check_current(const std::string& out, const std::string& stage, const std::string& key,
                   const std::vector<std::string>& outputs) {
  const std::string rp = (fs::path(out) / "stages" / (stage + ".json")).string();
  std::string text;
  if (!slurp(rp, text)) bug("current without a record file");
  nlohmann::json j;
  try {
    j = parse_stage_record(text, rp);
  } catch (const Error& e) {
    bug(std::string("current, but the record does not parse: ") + e.what());
  }
  if (j["key"] != key) bug("current with another key");
  std::vector<std::string> listed;
  for (const auto& o : j["outputs"]) listed.push_back(o["path"].get<std::string>());
  if (outputs.empty() ? listed.empty() : listed != outputs) bug("current with other outputs listed");
  for (const auto& o : j["outputs"]) {
    const std::string rel = o["path"].get<std::string>();
    if (rel.find('\0') != std::string::npos) bug("current with a NUL in output path (names another file)");
    std::string bytes;
    if (!slurp(fs::path(out) / rel, bytes)) bug("current, but " + rel + " is not a regular file");
    if (o["size"].get<std::uint64_t>() != bytes.size()) bug("current, but " + rel + " has another size");
    if (o["fnv1a"].get<std::string>() != fnv1a_hex(bytes)) bug("current, but " + rel + " has another hash");
  }
  try {
    const double s = recorded_seconds(out, stage);
    const double want = j.contains("seconds") ? j["seconds"].get<double>() : 0.0;
    if (!(s == want || (std::isnan(s) && std::isnan(want)))) bug("recorded_seconds differs from the record");
  } catch (const Error& e) {
    bug(std::string("current, but recorded_seconds throws: ") + e.what());
  }
}

// A name for a file in the run folder made from input bytes (no '/', no NUL, not . or ..).
std::string name_from(const std::uint8_t* data, std::size_t size) {
  std::string n = "x";
  for (std::size_t i = 0; i < size && n.size() < 12; ++i)
    if (data[i] != '/' && data[i] != 0) n.push_back(char(data[i]));
  return n;
}

void writer_round_trip(const std::uint8_t* data, std::size_t size, unsigned flags, const std::string& a) {
  const std::string& out = run_dir();
  std::vector<std::string> outputs = {"a.bin"};
  if (flags & 2) outputs.push_back("sub/b.ply");
  std::string extra;
  if (flags & 4) {
    extra = name_from(data, size);
    put(fs::path(out) / extra, a + "!");
    outputs.push_back(extra);
  }
  double seconds = 1.5;
  if (size >= 8) std::memcpy(&seconds, data + size - 8, 8);
  const std::string key = fnv1a_hex(std::string(reinterpret_cast<const char*>(data), size));
  nlohmann::json settings = {{"flags", flags}, {"n", size}};
  bool written = false;
  try {
    record_stage(out, "w", key, seconds, settings, outputs);
    written = true;
  } catch (const Error&) {
  }
  if (written) {
    const StageCheck c = check_stage(out, "w", key, outputs);
    if (!c.current) bug("a record just written by record_stage is not current: " + c.why);
    check_current(out, "w", key, outputs);
    if (check_stage(out, "w", key, {}).current != true) bug("record_stage's record not current for {}");
    if (check_stage(out, "w", key + "0", outputs).current) bug("current for another key");
    const double s = recorded_seconds(out, "w");
    if (s != (std::isfinite(seconds) ? seconds : 0.0)) bug("recorded_seconds does not return the seconds written");
    std::vector<std::string> fewer(outputs.begin(), outputs.end() - 1);
    if (!fewer.empty() && check_stage(out, "w", key, fewer).current) bug("current for a shorter output list");
    put(fs::path(out) / "a.bin", a + "?");
    if (check_stage(out, "w", key, outputs).current) bug("current after a.bin changed");
    put(fs::path(out) / "a.bin", a);
  }
  if (!extra.empty()) {
    std::error_code ec;
    fs::remove(fs::path(out) / extra, ec);
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 2) return 0;
  const unsigned flags = data[0];
  const std::size_t n = std::min<std::size_t>(data[1], size - 2);
  const std::string a(reinterpret_cast<const char*>(data + 2), n);
  const std::string text(reinterpret_cast<const char*>(data + 2 + n), size - 2 - n);

  // 1. Parsing from memory.
  try {
    const nlohmann::json j = parse_stage_record(text, "fuzz.json");
    if (!j.is_object() || !j["key"].is_string() || !j["outputs"].is_array()) bug("parsed without key/outputs");
    for (const auto& o : j["outputs"]) {
      const std::string p = o["path"].get<std::string>();
      if (p.empty() || p.front() == '/' || p.find('\0') != std::string::npos) bug("accepted path " + p);
      for (const auto& part : fs::path(p))
        if (part == "..") bug("accepted path " + p);
    }
    const nlohmann::json k = parse_stage_record(j.dump(), "dump.json");
    if (k != j) bug("dump -> parse changed the record");
  } catch (const Error&) {
  }

  // 2. Reading the record from disk and checking outputs against it.
  const std::string& out = run_dir();
  put(fs::path(out) / "a.bin", a);
  put(fs::path(out) / "sub" / "b.ply", kB);
  put(fs::path(out) / "stages" / "s.json", text);
  const std::vector<std::vector<std::string>> lists = {{}, {"a.bin"}, {"a.bin", "sub/b.ply"}};
  bool any = false;
  for (const auto& outputs : lists) {
    StageCheck c;
    try {
      c = check_stage(out, "s", "k0", outputs);
    } catch (const Error& e) {
      bug(std::string("check_stage threw instead of saying why: ") + e.what());
    }
    if (c.current) {
      any = true;
      check_current(out, "s", "k0", outputs);
    } else if (c.why.empty()) {
      bug("not current without a reason");
    }
  }
  if (!any) {
    try {
      (void)recorded_seconds(out, "s");
    } catch (const Error&) {
    }
  }

  // 3. The writer's records verify.
  writer_round_trip(data, size, flags, a);
  return 0;
}

// Seeds: a corpus folder named on the command line that is missing or empty
// gets inputs whose record text record_stage wrote for those outputs.
extern "C" int LLVMFuzzerInitialize(int* argc, char*** argv) {
  const std::vector<std::string> dirs = empty_corpus_dirs(*argc, *argv);
  if (dirs.empty()) return 0;
  const std::string& out = run_dir();
  const std::vector<std::string> contents = {"", "hello", std::string(40, 'z')};
  int k = 0;
  for (const auto& a : contents)
    for (unsigned flags : {0u, 2u}) {
      put(fs::path(out) / "a.bin", a);
      put(fs::path(out) / "sub" / "b.ply", kB);
      std::vector<std::string> outputs = {"a.bin"};
      if (flags & 2) outputs.push_back("sub/b.ply");
      record_stage(out, "s", "k0", 12.25 * (k + 1), {{"threads", 2}, {"name", "seed"}}, outputs);
      std::string text;
      slurp(fs::path(out) / "stages" / "s.json", text);
      const std::string input = std::string(1, char(flags)) + std::string(1, char(a.size())) + a + text;
      for (const auto& d : dirs) {
        fs::create_directories(d);
        put(fs::path(d) / ("seed-" + std::to_string(k)), input);
      }
      ++k;
    }
  // Not records: empty, plain JSON, a record missing its outputs.
  for (const std::string text : {"", "{}", "{\"key\": \"k0\"}", "{\"key\":\"k0\",\"outputs\":[]}"}) {
    const std::string input = std::string("\0\0", 2) + text;
    for (const auto& d : dirs) put(fs::path(d) / ("seed-" + std::to_string(k)), input);
    ++k;
  }
  return 0;
}
