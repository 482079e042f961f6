// audit: the whole pipeline over many recorded inputs, one after the other, and
// one table of their report.json figures (coverage, orbit diagnostics, quality,
// completion, stage times) with median and P90 rows.
//
//   audit --inputs DIR... --completion NAME [--cameras recorded|estimated] [--protocol measured|paper]
//         [full_pipeline's flags] [--shard i/n | --shard-count N] [--report-only] --out DIR
//   audit --write-synthetic DIR [--width W --height H] [--seed S]
//   audit --write-composite DIR --composite-of COLMAP_DIR [--seed S]
//
// Each input DIR (a COLMAP folder, as full_pipeline --colmap takes) runs into
// OUT/<basename of DIR>/ exactly as full_pipeline would, and resumes like it:
// finished stages are skipped. --cameras estimated is the user's path: COLMAP
// estimates the cameras from DIR/images' source frames alone (full_pipeline
// --images), and DIR's own model only scores the run (full_pipeline
// --reference). --cameras recorded (the default) uses DIR's model for
// everything: a lab figure when that model was estimated with every frame. An input that fails is recorded with its message
// and the audit goes on. --report-only runs nothing and reads OUT/<name>/report.json.
// --shard i/n takes every n-th input (sorted by path) so n machines can share the
// work; its tables are audit-<i>-of-<n>.{json,md,csv}, and a later --report-only
// run over all inputs without --shard writes the combined audit.{json,md,csv}.
// Without --shard the shard comes from the scheduler when there is one: a Slurm
// array task (SLURM_ARRAY_TASK_ID, _MIN, _COUNT) or a Kubernetes Indexed Job
// (JOB_COMPLETION_INDEX, with --shard-count N, the Job's completions); the tables
// record where it came from (audit/audit_shard.hpp, choose_shard).
// --write-synthetic DIR writes the project's embedded synthetic input as a COLMAP
// folder (DIR/images, DIR/sparse/0) and exits: an input for trying the audit, and
// its scheduler tests, on a machine without recorded data. --write-composite DIR
// writes the photographs of COLMAP_DIR (an object on black) over a textured wall
// rendered at each photograph's camera (pipeline/inputs/backdrop_composite.hpp):
// a real object on a backdrop whose borders disagree.
// Exit status: 0 every input succeeded, 1 some failed (or wait for external
// completion), 2 bad arguments.
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "cli.hpp"
#include "orbitforge/audit/audit_shard.hpp"
#include "orbitforge/audit/audit_table.hpp"
#include "orbitforge/core/huge_pages.hpp"
#include "orbitforge/io/colmap.hpp"
#include "orbitforge/io/image_io.hpp"
#include "orbitforge/pipeline/inputs/recorded_input.hpp"
#include "orbitforge/pipeline/pipeline.hpp"
#include "pipeline_flags.hpp"
#include "orbitforge/pipeline/inputs/backdrop_composite.hpp"
#include "orbitforge/pipeline/inputs/synthetic_pipeline_input.hpp"

using namespace orbitforge;
using S = float;
namespace fs = std::filesystem;

namespace {

const char* kDescription =
    "audit: the whole pipeline over many recorded inputs (COLMAP folders), one after the other, and one table of\n"
    "their report.json figures with median and P90 rows.\n"
    "  audit --inputs DIR... --completion NAME [--cameras recorded|estimated] [flags]\n"
    "        [--shard i/n | --shard-count N] [--report-only] --out DIR\n"
    "  audit --write-synthetic DIR [--width W --height H] [--seed S]\n"
    "  audit --write-composite DIR --composite-of COLMAP_DIR [--seed S]\n"
    "Each input runs into OUT/<basename of DIR>/ exactly as full_pipeline --colmap DIR would, and resumes like it.\n"
    "Audit defaults: --holdout-every 8, --compare-g1-paper, --oracle-bound. Every run writes OUT/settings.toml,\n"
    "which --config replays.";

// The folder name an input's outputs go to: the last component of its path.
std::string input_name(const std::string& dir) {
  fs::path p = fs::path(dir).lexically_normal();
  std::string name = p.filename().string();
  if (name.empty() || name == "." || name == "..") name = p.parent_path().filename().string();
  return name;
}

// An input as a COLMAP folder (DIR/images, DIR/sparse/0 without points): the
// frames with a camera and their cameras.
void write_as_colmap(const std::string& dir, const PipelineInput<S>& in) {
  fs::create_directories(fs::path(dir) / "images");
  write_colmap_text((fs::path(dir) / "sparse" / "0").string(), in.cameras);
  for (std::size_t i = 0; i < in.cameras.size(); ++i)
    if (in.cameras[i].valid) write_png((fs::path(dir) / "images" / in.cameras[i].name).string(), in.images[i]);
  std::fprintf(stderr, "audit: wrote %s to %s\n", in.description.c_str(), dir.c_str());
}

// The embedded synthetic input (full_pipeline's default) as a COLMAP folder that
// --inputs takes: every frame's PNG and the recorded (noisy) cameras, no points.
void write_synthetic(const std::string& dir, const cli::PipelineFlags& f) {
  SyntheticInputParams sp;
  sp.width = f.width > 0 ? f.width : 96;
  sp.height = f.height > 0 ? f.height : 96;
  sp.focal = 160.0 * sp.height / 128.0;  // full_pipeline's field of view
  if (f.params.seed != 0) sp.seed = f.params.seed;
  write_as_colmap(dir, synthetic_pipeline_input<S>(sp, f.params.threads));
}

// The photographs of `source` (an object on black, e.g. a Middlebury ring) over a
// textured wall, at their own size, as a COLMAP folder with the same cameras.
void write_composite(const std::string& dir, const std::string& source, const cli::PipelineFlags& f) {
  PipelineInput<S> in = load_colmap_input<S>(source, "1-", WorkingSize::native());
  BackdropCompositeParams bp;
  if (f.params.seed != 0) bp.seed = f.params.seed;
  bp.threads = f.params.threads;
  composite_on_backdrop(in, bp);
  write_as_colmap(dir, in);
}

std::optional<std::string> getenv_lookup(const std::string& name) {
  const char* v = std::getenv(name.c_str());
  return v ? std::optional<std::string>(v) : std::nullopt;
}

// Everything the command line sets.
struct Args {
  std::vector<std::string> inputs;
  std::string out, shard_text, shard_count_text, synthetic_dir, composite_dir, composite_of, cameras = "recorded";
  bool report_only = false;
  cli::PipelineFlags flags;
};

std::unique_ptr<CLI::App> define(Args& a) {
  auto app = std::make_unique<CLI::App>(kDescription, "audit");
  cli::setup(*app, /*with_config=*/true);
  const char* audit = "Audit";
  app->add_option("--inputs", a.inputs, "the input folders (COLMAP: images/ + sparse/0), each a row")->group(audit);
  app->add_option("--cameras", a.cameras,
                  "recorded: each DIR's own model (a lab figure when it saw every frame); estimated: COLMAP on "
                  "DIR/images' source frames alone, and DIR's model only scores the run")
      ->check(CLI::IsMember({"recorded", "estimated"}))
      ->group(audit);
  app->add_option("--shard", a.shard_text,
                  "i/n: every n-th input (sorted), the i-th of them; without it a Slurm array task's "
                  "SLURM_ARRAY_TASK_ID/_MIN/_COUNT choose the shard")
      ->group(audit);
  app->add_option("--shard-count", a.shard_count_text,
                  "N: with JOB_COMPLETION_INDEX (Kubernetes Indexed Job, 0-based): n = N")
      ->group(audit);
  app->add_flag("--report-only", a.report_only, "run nothing; read OUT/<name>/report.json")->group(audit);
  app->add_option("--write-synthetic", a.synthetic_dir,
                  "write the embedded synthetic input as a COLMAP folder and exit (default 96 x 96; --seed S picks "
                  "another scene)")
      ->group(audit);
  app->add_option("--write-composite", a.composite_dir,
                  "write --composite-of's photographs (an object on black) over a textured wall rendered at each "
                  "camera as a COLMAP folder and exit (--seed S picks another wall)")
      ->group(audit);
  app->add_option("--composite-of", a.composite_of, "the COLMAP folder --write-composite composites")->group(audit);
  cli::add_pipeline_flags(*app, a.flags);
  app->add_option("--out", a.out, "output folder: OUT/<name>/ per input, and the tables");
  return app;
}

}  // namespace

int main(int argc, char** argv) {
  relaunch_with_huge_pages(argv);  // first: glibc reads its tunables only at start
  return cli::run([&]() -> int {
    Args args;
    // Audit defaults: supported views scored on source frames no reconstruction trained on, and both comparisons.
    args.flags.holdout_every = 8;
    args.flags.params.compare_g1_paper = args.flags.params.oracle_bound = true;
    const std::unique_ptr<CLI::App> app = cli::parse_with_protocol(
        args, argc, argv, define, [](const Args& a) { return a.flags.protocol; },
        [](Args& a, Protocol p) { cli::begin_pipeline_flags(a.flags, p); });
    cli::end_pipeline_flags(*app, args.flags);
    const std::vector<std::string>& inputs = args.inputs;
    const std::string &out = args.out, &cameras = args.cameras;
    const bool report_only = args.report_only, completion_set = app->count("--completion") > 0;
    const cli::PipelineFlags& flags = args.flags;
    const std::string usage_hint = "\n(audit --help lists every flag)";
    PipelineParams p = flags.params;
    if (!args.synthetic_dir.empty()) {
      if (!inputs.empty() || !out.empty())
        throw cli::UsageError("audit: --write-synthetic DIR runs on its own (no --inputs, no --out)");
      write_synthetic(args.synthetic_dir, flags);
      return 0;
    }
    if (!args.composite_dir.empty() || !args.composite_of.empty()) {
      if (args.composite_dir.empty() || args.composite_of.empty())
        throw cli::UsageError("audit: --write-composite DIR and --composite-of COLMAP_DIR go together");
      if (!inputs.empty() || !out.empty())
        throw cli::UsageError("audit: --write-composite DIR runs on its own (no --inputs, no --out)");
      write_composite(args.composite_dir, args.composite_of, flags);
      return 0;
    }
    if (inputs.empty()) throw cli::UsageError("audit: --inputs DIR... is required" + usage_hint);
    if (flags.image_order == ImageOrder::ring && cameras == "estimated")
      throw cli::UsageError("audit: --image-order ring goes with --cameras recorded (the estimated path chooses the "
                            "source frames by name before COLMAP gives them cameras)");
    // CLI11 takes the word after a bare --inputs as its value, even a flag.
    for (const auto& dir : inputs)
      if (dir.rfind("-", 0) == 0) throw cli::UsageError("audit: --inputs needs at least one folder, got '" + dir + "'");
    if (out.empty()) throw cli::UsageError("audit: --out DIR is required" + usage_hint);
    // The oracle reads frames the method would not have: an audit says which completion it measured.
    if (!report_only && !completion_set)
      throw cli::UsageError("audit: name the completion (--completion oracle|perturbed|external|none)" + usage_hint);
    AuditShardChoice choice;
    try {
      choice = choose_shard(args.shard_text, args.shard_count_text, getenv_lookup);
    } catch (const Error& e) {
      throw cli::UsageError(std::string("audit: shard: ") + e.what());
    }
    const AuditShard shard = choice.shard;
    if (choice.source != "none")
      std::fprintf(stderr, "audit: shard %d/%d from %s (%s)\n", shard.index, shard.count, choice.source.c_str(),
                   choice.detail.c_str());
    // Outputs go to OUT/<basename>: two inputs with one name would share a folder.
    std::set<std::string> names;
    for (const auto& dir : inputs) {
      const std::string name = input_name(dir);
      if (name.empty()) throw cli::UsageError("audit: cannot name the outputs of input '" + dir + "'");
      if (!names.insert(name).second)
        throw cli::UsageError("audit: two inputs are named '" + name + "' (outputs go to OUT/<basename of DIR>)");
    }

    const std::vector<std::string> mine = shard_inputs(inputs, shard);
    fs::create_directories(out);
    // The settings as this audit resolved them (OUT/settings.toml), recorded in each input's report.json too.
    if (!report_only) p.invocation = cli::record_invocation(*app, argc, argv, out);
    std::vector<AuditRow> rows;
    for (std::size_t k = 0; k < mine.size(); ++k) {
      const std::string& dir = mine[k];
      const std::string name = input_name(dir);
      const std::string dest = (fs::path(out) / name).string();
      std::fprintf(stderr, "audit: [%zu/%zu] %s -> %s\n", k + 1, mine.size(), dir.c_str(), dest.c_str());
      if (!report_only) {
        const auto t0 = std::chrono::steady_clock::now();
        AuditRow failed;
        failed.name = name;
        try {
          // The same loading and settings as full_pipeline --colmap, or --images DIR/images --reference DIR.
          if (cameras == "estimated") {
            CameraStageParams cp = cli::camera_stage_params(flags);
            cp.images = (fs::path(dir) / "images").string();
            std::string key;
            const PipelineInput<S> input = cli::load_estimated_input<S>("audit", dest, cp, flags, dir, &key);
            PipelineRun<S> run;
            run.keys["cameras"] = key;
            run_pipeline(input, p, dest, nullptr, &run);
          } else {
            std::string key;
            const PipelineInput<S> input = cli::load_recorded_input<S>("audit", dir, dest, flags, &key);
            PipelineRun<S> run;
            if (!key.empty()) run.keys["points"] = key;
            run_pipeline(input, p, dest, nullptr, &run);
          }
        } catch (const PipelineStopped& e) {
          failed.error = e.what();
          failed.status = "stopped";
        } catch (const std::exception& e) {
          failed.error = cli::describe(e);
        }
        const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        if (!failed.error.empty()) {
          std::fprintf(stderr, "audit: %s %s after %.1f s: %s\n", name.c_str(),
                       failed.status == "stopped" ? "stopped" : "failed", secs, failed.error.c_str());
          rows.push_back(failed);
          continue;
        }
        std::fprintf(stderr, "audit: %s done in %.1f s\n", name.c_str(), secs);
      }
      rows.push_back(read_audit_row(name, dest));
      if (report_only && !rows.back().error.empty())
        std::fprintf(stderr, "audit: %s: %s\n", name.c_str(), rows.back().error.c_str());
    }

    nlohmann::json table = audit_table(rows);
    nlohmann::json settings = {{"mode", report_only ? "report-only" : "run"},
                               {"shard", std::to_string(shard.index) + "/" + std::to_string(shard.count)},
                               {"shard_source", choice.source},
                               {"shard_detail", choice.detail},
                               {"inputs", mine}};
    if (!report_only) {
      const auto size = cli::working_size(flags);
      settings["protocol"] = protocol_name(flags.protocol);
      settings["frames"] = flags.frames;
      settings["cameras"] = cameras;
      settings["completion"] = p.completion;
      settings["working_size"] = size.describe();
      settings["holdout_every"] = flags.holdout_every;
      settings["iters"] = p.iters_g0;
      settings["threads"] = p.threads;
    }
    table["audit"] = settings;
    const std::string stem = choice.source == "none" ? std::string("audit")
                                                : "audit-" + std::to_string(shard.index) + "-of-" +
                                                      std::to_string(shard.count);
    const std::string md = audit_markdown(table);
    write_file_atomic((fs::path(out) / (stem + ".json")).string(), table.dump(1) + "\n");
    write_file_atomic((fs::path(out) / (stem + ".md")).string(), md);
    write_file_atomic((fs::path(out) / (stem + ".csv")).string(), audit_csv(table));
    std::cout << md;
    std::size_t ok = 0;
    for (const auto& r : table["rows"]) ok += r["status"] == "ok" ? 1 : 0;
    std::fprintf(stderr, "audit: %zu of %zu inputs succeeded; tables in %s/%s.{json,md,csv}\n", ok, rows.size(),
                 out.c_str(), stem.c_str());
    return ok == rows.size() ? 0 : 1;
  });
}
