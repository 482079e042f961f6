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

#include "orbitforge/pipeline/protocol.hpp"
#include "orbitforge/pipeline/run_state.hpp"
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

// A reconstruction's key covers every training setting that can change it, and
// none of a disabled feature's: a long run resumed with another learning rate
// trains again, one resumed after a disabled feature's default moved does not.
TEST_CASE("stage records: training settings key what changes the result, not what is off", "[pipeline][stage_record]") {
  const PipelineParams p;
  const auto key = [&](const TrainParams& t) { return pipeline_detail::train_settings<float>(t, p).dump(); };
  TrainParams base = paper_train_params(10000);
  base.deformable = true;
  const std::string k0 = key(base);

  const std::vector<std::pair<const char*, void (*)(TrainParams&)>> changes = {
      {"position lr", [](TrainParams& t) { t.position_lr_init *= 2; }},
      {"scaling lr", [](TrainParams& t) { t.scaling_lr = 5e-3; }},
      {"adam eps", [](TrainParams& t) { t.adam.eps = 1e-8; }},
      {"SH interval", [](TrainParams& t) { t.sh_degree_interval = 500; }},
      {"densify interval", [](TrainParams& t) { t.densify_schedule.densify_interval = 50; }},
      {"opacity reset", [](TrainParams& t) { t.densify_schedule.opacity_reset_interval = 1000; }},
      {"gaussian budget", [](TrainParams& t) { t.densify_params.max_gaussians = 30000; }},
      {"pruning floor", [](TrainParams& t) { t.densify_params.min_gaussians = 1000; }},
      {"random background", [](TrainParams& t) { t.random_background = true; }},
      {"exposure compensation", [](TrainParams& t) { t.exposure_compensation = true; }},
      {"field width", [](TrainParams& t) { t.field.width = 64; }},
      {"time frequencies", [](TrainParams& t) { t.field.t_frequencies = 6; }},
      {"head init", [](TrainParams& t) { t.field.head_init_scale = 0.01; }},
      {"deform lr", [](TrainParams& t) { t.deform_lr_final = 8e-6; }},
      {"warm-up", [](TrainParams& t) { t.warmup_iterations = 750; }},
      {"time noise", [](TrainParams& t) { t.time_noise = 0; }},
      {"still check", [](TrainParams& t) { t.still_check_iterations = 500; }},
      {"coarse levels", [](TrainParams& t) { t.coarse_levels = 1; }},
      {"plateau", [](TrainParams& t) { t.plateau_window = 500; }},
      {"densify passes", [](TrainParams& t) { t.densify_interval_passes = 1; }},
      {"reset passes", [](TrainParams& t) { t.opacity_reset_passes = 4; }},
      {"learned background", [](TrainParams& t) { t.learned_background = true; }},
  };
  for (const auto& c : changes) {
    INFO(c.first);
    TrainParams t = base;
    c.second(t);
    CHECK(key(t) != k0);
  }

  const std::vector<std::pair<const char*, void (*)(TrainParams&)>> off = {
      {"still gain, check off", [](TrainParams& t) { t.still_gain_db = 0.1; }},
      {"background rate, not learned", [](TrainParams& t) { t.background_lr = 0.5; }},
      {"still samples, check off", [](TrainParams& t) { t.still_bake_samples = 8; }},
      {"still region gain, check off", [](TrainParams& t) { t.still_region_gain_db = 1.5; }},
      {"still holdout, check off", [](TrainParams& t) { t.still_holdout_every = 5; }},
      {"coarse fraction, coarse off", [](TrainParams& t) { t.coarse_fraction = 0.75; }},
      {"plateau tolerance, plateau off", [](TrainParams& t) { t.plateau_tolerance = 0.02; }},
      {"time noise steps, noise off", [](TrainParams& t) { t.time_noise_steps = 1000; }},
      {"threads", [](TrainParams& t) { t.threads = 7; }},
      {"exposure rate, compensation off", [](TrainParams& t) { t.exposure_lr = 0.01; }},
      {"screen-size fraction, fixed background", [](TrainParams& t) { t.densify_params.max_screen_fraction = 0.3; }},
  };
  TrainParams quiet = base;
  quiet.time_noise = 0;
  const std::string kq = key(quiet);
  for (const auto& c : off) {
    INFO(c.first);
    TrainParams t = quiet;
    c.second(t);
    CHECK(key(t) == kq);
  }
  // The screen-size fraction acts with a random background only, and is keyed then.
  TrainParams random_bg = base;
  random_bg.random_background = true;
  TrainParams random_bg_other = random_bg;
  random_bg_other.densify_params.max_screen_fraction = 0.3;
  CHECK(key(random_bg_other) != key(random_bg));
  // The frames the check holds back are keyed when it runs.
  TrainParams checked = base;
  checked.still_check_iterations = 500;
  TrainParams checked_other = checked;
  checked_other.still_holdout_every = 0;
  CHECK(key(checked_other) != key(checked));
  // A static reconstruction ignores every deformation setting.
  TrainParams still = base;
  still.deformable = false;
  TrainParams still_other = still;
  still_other.field.width = 64;
  still_other.deform_lr_init = 1e-3;
  still_other.still_check_iterations = 500;
  CHECK(key(still_other) == key(still));
  CHECK(key(still) != k0);

#if defined(__x86_64__) && defined(__linux__)
  // A tripwire, not a result: a setting added to (or removed from) these structs
  // must be keyed in train_settings, then these sizes updated.
  CHECK(sizeof(TrainParams) == 472);
  CHECK(sizeof(DensifyParams) == 88);
  CHECK(sizeof(DensifySchedule) == 16);
  CHECK(sizeof(DeformationFieldParams) == 40);
  CHECK(sizeof(AdamParams) == 24);
#endif
}
