// The training checkpoint format (io/checkpoint.hpp): a record round-trips bit
// for bit, static and deformable; a damaged file is refused naming the file; a
// record inconsistent in itself is refused naming what.
#include <catch2/catch.hpp>

#include <cstring>
#include <random>
#include <sstream>

#include "io_test_util.hpp"
#include "orbitforge/io/checkpoint.hpp"

using namespace orbitforge;
using orbitforge_test::error_of;

namespace {

template <class S>
TrainingCheckpoint<S> make_checkpoint(bool deformable) {
  TrainingCheckpoint<S> c;
  c.iteration = 700;
  c.budget = 3000;
  c.frame_count = 3;
  c.seed = 11;
  c.deformable = deformable;
  c.extent = S(1.5);
  c.elapsed_s = 12.25;
  const std::size_t n = 5;
  c.scene.resize(n, 1);
  std::mt19937 rng(4);
  std::normal_distribution<double> nd;
  for (auto* v : {&c.scene.means, &c.scene.log_scales, &c.scene.opacity_logits, &c.scene.sh})
    for (S& x : *v) x = S(nd(rng));
  const char* names[6] = {"means", "rotations", "scales", "opacities", "sh_dc", "sh_rest"};
  const int widths[6] = {3, 4, 3, 1, 3, 9};
  for (int g = 0; g < 6; ++g) c.adam.add_group(names[g], n, widths[g], S(0.01));
  std::ostringstream rs;
  rs << rng;
  c.rng_state = rs.str();
  c.order = {2, 0, 1, 1};  // frame 1 weighted twice
  c.cursor = 3;
  c.densify_grad_sum.assign(n, 0.5);
  c.densify_count.assign(n, 2);
  c.densify_max_radius.assign(n, S(3));
  if (deformable) {
    DeformationFieldParams fp;
    fp.depth = 2;
    fp.width = 8;
    c.field = std::make_unique<DeformationField<S>>(fp);
    c.field_adam.add_group("deformation", c.field->parameter_count(), 1, S(0));
  }
  return c;
}

template <class S>
std::string bytes_of(const TrainingCheckpoint<S>& c) {
  std::ostringstream os(std::ios::binary);
  write_checkpoint(os, c);
  return os.str();
}

}  // namespace

TEMPLATE_TEST_CASE("checkpoint records round-trip bit for bit", "[io][checkpoint]", float, double) {
  for (bool deformable : {false, true}) {
    const TrainingCheckpoint<TestType> c = make_checkpoint<TestType>(deformable);
    const std::string a = bytes_of(c);
    std::istringstream is(a, std::ios::binary);
    const TrainingCheckpoint<TestType> r = read_checkpoint<TestType>(is);
    REQUIRE(r.iteration == 700);
    REQUIRE(r.order == c.order);
    REQUIRE(r.scene.means == c.scene.means);
    REQUIRE(bool(r.field) == deformable);
    REQUIRE(bytes_of(r) == a);  // every field, in order
  }
}

TEST_CASE("checkpoint records keep the still-scene and plateau state", "[io][checkpoint]") {
  TrainingCheckpoint<float> c = make_checkpoint<float>(true);
  c.shortcuts.still_checked = true;
  c.shortcuts.field_baked = true;  // baked: no field follows
  c.field.reset();
  c.shortcuts.field_gain_db = 0.03;
  c.shortcuts.field_region_gain_db = 0.71;
  c.shortcuts.field_region = 21;
  c.shortcuts.plateau_sum = 1.5;
  c.shortcuts.plateau_previous = 0.25;
  c.shortcuts.plateau_last = 0.24;
  c.shortcuts.stopped = true;
  const std::string a = bytes_of(c);
  std::istringstream is(a, std::ios::binary);
  const TrainingCheckpoint<float> r = read_checkpoint<float>(is);
  REQUIRE(r.deformable);
  REQUIRE(r.shortcuts.still_checked);
  REQUIRE(r.shortcuts.field_baked);
  REQUIRE_FALSE(r.field);
  REQUIRE(r.shortcuts.field_gain_db == 0.03);
  REQUIRE(r.shortcuts.field_region_gain_db == 0.71);
  REQUIRE(r.shortcuts.field_region == 21);
  REQUIRE(r.shortcuts.plateau_previous == 0.25);
  REQUIRE(r.shortcuts.plateau_last == 0.24);
  REQUIRE(r.shortcuts.stopped);
  REQUIRE(bytes_of(r) == a);
  // A deformable record neither baked nor holding its field, or a static one
  // with a baked field, is not written.
  c.shortcuts.field_baked = false;
  REQUIRE_THROWS_WITH(bytes_of(c), Catch::Contains("without its deformation field"));
  TrainingCheckpoint<float> s = make_checkpoint<float>(false);
  s.shortcuts.field_baked = true;
  REQUIRE_THROWS_WITH(bytes_of(s), Catch::Contains("baked field"));
}

TEST_CASE("checkpoint files: a damaged byte, a cut or an inconsistent record is refused by name",
          "[io][checkpoint]") {
  orbitforge_test::TempDir dir("checkpoint");
  const std::string path = (dir.path() / "partial.bin").string();
  write_checkpoint_file(path, make_checkpoint<float>(true));
  REQUIRE(read_checkpoint_file<float>(path).deformable);

  std::string bytes = orbitforge_test::slurp(path);
  bytes[bytes.size() / 2] ^= 0x10;
  orbitforge_test::spit(path, bytes);
  std::string e = error_of([&] { read_checkpoint_file<float>(path); });
  REQUIRE_THAT(e, Catch::Contains(path) && Catch::Contains("checksum mismatch"));
  orbitforge_test::spit(path, bytes.substr(0, bytes.size() - 30));
  REQUIRE_THAT(error_of([&] { read_checkpoint_file<float>(path); }), Catch::Contains("no checksum trailer"));

  // A record with a valid checksum but contradicting itself (the fuzzers' mode).
  TrainingCheckpoint<float> bad = make_checkpoint<float>(false);
  bad.cursor = 9;
  std::istringstream is(bytes_of(bad), std::ios::binary);
  REQUIRE_THAT(error_of([&] { read_checkpoint<float>(is); }), Catch::Contains("frame cursor 9"));
  bad = make_checkpoint<float>(false);
  bad.densify_count.pop_back();
  std::istringstream is2(bytes_of(bad), std::ios::binary);
  REQUIRE_THAT(error_of([&] { read_checkpoint<float>(is2); }), Catch::Contains("densification statistics"));
  // Double precision reads refuse a float record.
  std::istringstream is3(bytes_of(make_checkpoint<float>(false)), std::ios::binary);
  REQUIRE_THAT(error_of([&] { read_checkpoint<double>(is3); }), Catch::Contains("4-byte scalars"));
}
