// One owner for each training setting the pipeline sets itself: a value in
// params.train that its owner contradicts is refused, naming both fields; one
// left at TrainParams's default or equal to the owner's takes the owner's value.
#include <catch2/catch.hpp>

#include <array>
#include <functional>
#include <string>

#include "orbitforge/pipeline/params.hpp"
#include "orbitforge/pipeline/pipeline.hpp"
#include "orbitforge/pipeline/protocol.hpp"
#include "orbitforge/pipeline/run_state.hpp"

using namespace orbitforge;

namespace {

struct Owned {
  const char* field;                             // params.train.<field>
  const char* owner;                             // what the message names as its owner
  std::function<void(PipelineParams&)> conflict;  // sets params.train.<field> against its owner
  std::function<void(PipelineParams&)> agree;     // sets params.train.<field> to its owner's value
  std::function<bool(const TrainParams&)> took;   // the trained-with settings show the agreed value
};

std::vector<Owned> owned_fields() {
  return {
      {"iterations", "params.iters_g0", [](PipelineParams& p) { p.train.iterations = p.iters_g0 + 1; },
       [](PipelineParams& p) { p.iters_g0 = p.iters_g1 = 1234, p.train.iterations = 1234; },
       [](const TrainParams& t) { return t.iterations == 1234; }},
      {"deformable", "params.g1_deformable", [](PipelineParams& p) { p.train.deformable = true; },
       [](PipelineParams& p) { p.deformable = p.g1_deformable = p.train.deformable = true; },
       [](const TrainParams& t) { return t.deformable; }},
      {"seed", "params.seed", [](PipelineParams& p) { p.train.seed = p.seed + 7; },
       [](PipelineParams& p) { p.seed = p.train.seed = 7; }, [](const TrainParams& t) { return t.seed == 7; }},
      {"threads", "params.threads", [](PipelineParams& p) { p.train.threads = 3; },
       [](PipelineParams& p) { p.threads = p.train.threads = 2; }, [](const TrainParams& t) { return t.threads == 2; }},
      {"min_densify_interval", "params.min_densify_interval",
       [](PipelineParams& p) { p.train.min_densify_interval = p.min_densify_interval + 1; },
       [](PipelineParams& p) { p.min_densify_interval = p.train.min_densify_interval = 20; },
       [](const TrainParams& t) { return t.min_densify_interval == 20; }},
      {"background", "the input's background", [](PipelineParams& p) { p.train.background = {0.5, 0.5, 0.5}; },
       [](PipelineParams& p) { p.train.background = {1, 1, 1}; },
       [](const TrainParams& t) { return t.background == std::array<double, 3>{{1, 1, 1}}; }},
  };
}

}  // namespace

TEST_CASE("pipeline settings: params.train's pipeline-owned fields are refused by name or take effect",
          "[pipeline][params]") {
  PipelineInput<float> input;
  input.background = {1, 1, 1};
  for (const Owned& o : owned_fields()) {
    INFO("params.train." << o.field);
    PipelineRun<float> run;
    run.input = &input;

    // Left at the default: the owner's value is trained with.
    run.params = PipelineParams{};
    REQUIRE_NOTHROW(run.train_params(run.params.iters_g0, run.params.deformable));

    // Contradicting the owner: refused, naming both fields, by train_params and
    // by run_pipeline before any stage runs.
    run.params = PipelineParams{};
    o.conflict(run.params);
    const std::string train_field = std::string("params.train.") + o.field;
    REQUIRE_THROWS_WITH(run.train_params(run.params.iters_g0, run.params.deformable),
                        Catch::Contains(train_field) && Catch::Contains(o.owner));
    REQUIRE_THROWS_WITH(check_train_owners(run.params, input.background),
                        Catch::Contains(train_field) && Catch::Contains(o.owner));
    REQUIRE_THROWS_WITH(run_pipeline(input, run.params, "/nonexistent/orbitforge_train_owners"),
                        Catch::Contains(train_field));

    // Equal to the owner's value: accepted, and in effect.
    run.params = PipelineParams{};
    o.agree(run.params);
    const TrainParams t = run.train_params(run.params.iters_g0, run.params.deformable);
    REQUIRE(o.took(t));
  }
}

TEST_CASE("pipeline settings: iters_g0 and iters_g1 both own the budget", "[pipeline][params]") {
  PipelineInput<float> input;
  PipelineParams p;
  p.iters_g0 = 500;
  p.iters_g1 = 800;
  p.train.iterations = 500;  // G0's, not G1's
  REQUIRE_THROWS_WITH(check_train_owners(p, input.background),
                      Catch::Contains("params.train.iterations = 500") && Catch::Contains("params.iters_g1 = 800"));
}

TEST_CASE("pipeline settings: the paper protocol leaves the owned fields to their owners", "[pipeline][params]") {
  PipelineParams p;
  apply_protocol(p, Protocol::paper);
  REQUIRE_NOTHROW(check_train_owners(p, {1, 1, 1}));
  p.iters_g0 = p.iters_g1 = 2000;  // --protocol paper --iters 2000
  REQUIRE_NOTHROW(check_train_owners(p, {1, 1, 1}));
}

TEST_CASE("pipeline settings: a learned background is refused, since every stage renders with the input's",
          "[pipeline][params]") {
  PipelineParams p;
  p.train.learned_background = true;
  REQUIRE_THROWS_WITH(check_train_owners(p, {1, 1, 1}), Catch::Contains("learned_background"));
}
