// Stage records (pipeline/stage_record.hpp): what record_stage writes for a stage's
// outputs is current for exactly that key and those outputs, and stops being
// current when an output changes. The cases found by fuzz/fuzz_stage_record: a
// name containing ".." that is not a ".." component ("clip..v2.png") was refused
// by the reader (the stage ran again forever), non-finite seconds were written as
// null (the record was unreadable), a name that is not UTF-8 escaped as a JSON
// exception, and a path with a NUL named the file before it.
#include <catch2/catch.hpp>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <string>
#include <vector>

#include <unistd.h>

#include "orbitforge/pipeline/stage_record.hpp"

using namespace orbitforge;
namespace fs = std::filesystem;

namespace {

struct RunFolder {
  fs::path dir = fs::temp_directory_path() / ("orbitforge_stage_record_" + std::to_string(::getpid()));
  RunFolder() {
    fs::remove_all(dir);
    fs::create_directories(dir / "sub");
  }
  ~RunFolder() {
    std::error_code ec;
    fs::remove_all(dir, ec);
  }
  void put(const std::string& rel, const std::string& bytes) const {
    std::ofstream f(dir / rel, std::ios::binary | std::ios::trunc);
    f << bytes;
  }
  std::string out() const { return dir.string(); }
};

}  // namespace

TEST_CASE("stage records: written records verify, changed outputs do not", "[pipeline][stage_record]") {
  RunFolder run;
  const std::vector<std::string> outputs = {"a.bin", "clip..v2.png", "sub/b.ply"};
  for (const auto& o : outputs) run.put(o, "content of " + o);
  record_stage(run.out(), "s", "k1", 2.5, {{"threads", 2}}, outputs);
  CHECK(check_stage(run.out(), "s", "k1", outputs).current);
  CHECK(check_stage(run.out(), "s", "k1", {}).current);
  CHECK(recorded_seconds(run.out(), "s") == 2.5);
  CHECK(check_stage(run.out(), "s", "k2", outputs).why == "inputs or settings changed");
  CHECK(check_stage(run.out(), "s", "k1", {"a.bin"}).why == "the record lists other outputs");
  run.put("clip..v2.png", "changed");
  CHECK_FALSE(check_stage(run.out(), "s", "k1", outputs).current);
}

TEST_CASE("stage records: non-finite seconds are left out, not written as null", "[pipeline][stage_record]") {
  RunFolder run;
  run.put("a.bin", "x");
  for (double s : {std::numeric_limits<double>::quiet_NaN(), std::numeric_limits<double>::infinity()}) {
    record_stage(run.out(), "s", "k", s, nlohmann::json::object(), {"a.bin"});
    CHECK(check_stage(run.out(), "s", "k", {"a.bin"}).current);
    CHECK(recorded_seconds(run.out(), "s") == 0.0);
  }
}

TEST_CASE("stage records: names JSON or the run folder cannot hold are refused", "[pipeline][stage_record]") {
  RunFolder run;
  const std::string latin1 = "caf\xe9.png";  // not UTF-8
  run.put(latin1, "x");
  CHECK_THROWS_AS(record_stage(run.out(), "s", "k", 1, nlohmann::json::object(), {latin1}), Error);
  CHECK_THROWS_AS(record_stage(run.out(), "s", "k", 1, {{"name", latin1}}, {}), Error);
  CHECK_THROWS_AS(record_stage(run.out(), "s", "k", 1, nlohmann::json::object(), {"../a.bin"}), Error);

  const std::string record = R"({"key": "k", "outputs": [{"path": "P", "size": 1, "fnv1a": "44bda3d473cdc381"}]})";
  auto with_path = [&record](const std::string& p) {
    std::string r = record;
    return r.replace(r.find("\"P\""), 3, "\"" + p + "\"");
  };
  CHECK_NOTHROW(parse_stage_record(with_path("clip..v2.png"), "r"));
  CHECK_NOTHROW(parse_stage_record(with_path("sub/..x"), "r"));
  for (const char* bad : {"../a.bin", "sub/../../a.bin", "..", "/etc/passwd", "", "a.bin\\u0000.png"}) {
    INFO(bad);
    CHECK_THROWS_AS(parse_stage_record(with_path(bad), "r"), Error);
  }
  // The NUL case on disk: a.bin holds "x" (FNV-1a 44bda3d473cdc381); a record naming
  // "a.bin<NUL>.png" with a.bin's size and hash is not current.
  run.put("a.bin", "x");
  fs::create_directories(run.dir / "stages");
  std::ofstream(run.dir / "stages" / "n.json") << with_path("a.bin\\u0000.png");
  CHECK_FALSE(check_stage(run.out(), "n", "k", {}).current);
  std::ofstream(run.dir / "stages" / "n.json") << with_path("a.bin");
  CHECK(check_stage(run.out(), "n", "k", {}).current);
}
