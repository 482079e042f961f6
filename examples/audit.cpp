// audit: the whole pipeline over many recorded inputs, one after the other, and
// one table of their report.json figures (coverage, orbit diagnostics, quality,
// completion, stage times) with median and P90 rows.
//
//   audit --inputs DIR... [--frames A-B] [--completion external|oracle|none]
//         [--width W --height H] [--iters N] [--threads N] [--shard i/n] [--report-only] [--quiet] --out DIR
//
// Each input DIR (a COLMAP folder, as full_pipeline --colmap takes) runs into
// OUT/<basename of DIR>/ exactly as full_pipeline would, and resumes like it:
// finished stages are skipped. An input that fails is recorded with its message
// and the audit goes on. --report-only runs nothing and reads OUT/<name>/report.json.
// --shard i/n takes every n-th input (sorted by path) so n machines can share the
// work; its tables are audit-<i>-of-<n>.{json,md,csv}, and a later --report-only
// run over all inputs without --shard writes the combined audit.{json,md,csv}.
// Exit status: 0 every input succeeded, 1 some failed (or wait for external
// completion), 2 bad arguments.
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <set>
#include <string>
#include <vector>

#include "cli.hpp"
#include "orbitforge/pipeline/audit.hpp"
#include "orbitforge/pipeline/pipeline.hpp"

using namespace orbitforge;
using S = float;
namespace fs = std::filesystem;

namespace {

const char* kUsage =
    "usage: audit --inputs DIR... [--frames A-B] [--completion external|oracle|none]\n"
    "             [--width W --height H] [--iters N] [--threads N] [--shard i/n] [--report-only] [--quiet] --out DIR\n";

// The folder name an input's outputs go to: the last component of its path.
std::string input_name(const std::string& dir) {
  fs::path p = fs::path(dir).lexically_normal();
  std::string name = p.filename().string();
  if (name.empty() || name == "." || name == "..") name = p.parent_path().filename().string();
  return name;
}

}  // namespace

int main(int argc, char** argv) {
  return cli::run([&]() -> int {
    std::vector<std::string> inputs;
    std::string frames, out, shard_text;
    PipelineParams p;
    int width = 0, height = 0;
    bool report_only = false;
    int holdout_every = 8;  // supported views scored on source frames no reconstruction trained on
    p.compare_g1_paper = p.oracle_bound = true;
    cli::ArgWalker a("audit", argc, argv);
    bool more = a.next();
    while (more) {
      const std::string f = a.flag();
      if (f == "--inputs") {
        bool any = false;
        while ((more = a.next()) && a.flag().rfind("--", 0) != 0) {
          inputs.push_back(a.flag());
          any = true;
        }
        if (!any) throw cli::UsageError("audit: --inputs needs at least one folder\n" + std::string(kUsage));
        continue;
      }
      if (f == "--frames") frames = a.value();
      else if (f == "--completion") {
        p.completion = a.value();
        if (p.completion != "external" && p.completion != "oracle" && p.completion != "none" &&
            p.completion != "perturbed")
          throw cli::UsageError("audit: --completion must be external, oracle, perturbed or none, got '" +
                                p.completion + "'");
      } else if (f == "--holdout-every") holdout_every = int(cli::parse_int("audit", f, a.value(), 0));
      else if (f == "--no-comparisons") p.compare_g1_paper = p.oracle_bound = false;
      else if (f == "--g1-data") p.g1_data = parse_g1_data(a.value());
      else if (f == "--g1-arc-renders") p.g1_arc_renders = true;
      else if (f == "--g1-deformable") p.g1_deformable = true;
      else if (f == "--g1-static") p.g1_deformable = false;
      else if (f == "--g1-source-repeats") p.g1_source_repeats = int(cli::parse_int("audit", f, a.value(), 1));
      else if (f == "--g1-completion-repeats") p.g1_completion_repeats = int(cli::parse_int("audit", f, a.value(), 1));
      else if (f == "--width") width = int(cli::parse_int("audit", f, a.value(), 8));
      else if (f == "--height") height = int(cli::parse_int("audit", f, a.value(), 8));
      else if (f == "--iters") p.iters_g0 = p.iters_g1 = int(cli::parse_int("audit", f, a.value(), 1));
      else if (f == "--threads") p.threads = int(cli::parse_int("audit", f, a.value(), 0));
      else if (f == "--shard") shard_text = a.value();
      else if (f == "--report-only") report_only = true;
      else if (f == "--quiet") p.progress = false;
      else if (f == "--out") out = a.value();
      else if (f == "-h" || f == "--help") {
        std::cout << kUsage;
        return 0;
      } else
        throw cli::UsageError("audit: unknown argument '" + f + "'\n" + kUsage);
      more = a.next();
    }
    if (inputs.empty()) throw cli::UsageError("audit: --inputs DIR... is required\n" + std::string(kUsage));
    if (out.empty()) throw cli::UsageError("audit: --out DIR is required\n" + std::string(kUsage));
    AuditShard shard;
    if (!shard_text.empty()) {
      try {
        shard = parse_shard(shard_text);
      } catch (const Error& e) {
        throw cli::UsageError(std::string("audit: --shard: ") + e.what());
      }
    }
    if (!frames.empty()) {
      try {
        parse_frame_range(frames);
      } catch (const Error& e) {
        throw cli::UsageError(std::string("audit: --frames: ") + e.what());
      }
    }
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
          // The same loading and settings as full_pipeline --colmap.
          PipelineInput<S> input = load_colmap_input<S>(dir, frames.empty() ? std::string("1-33") : frames,
                                                        width > 0 ? width : 512, height > 0 ? height : 512);
          withhold_every(input, holdout_every);
          choose_background(input);
          run_pipeline(input, p, dest);
        } catch (const PipelineStopped& e) {
          failed.error = e.what();
          failed.status = "stopped";
        } catch (const std::exception& e) {
          failed.error = e.what();
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
                               {"inputs", mine}};
    if (!report_only) {
      settings["frames"] = frames.empty() ? std::string("1-33") : frames;
      settings["completion"] = p.completion;
      settings["width"] = width > 0 ? width : 512;
      settings["height"] = height > 0 ? height : 512;
      settings["iters"] = p.iters_g0;
      settings["threads"] = p.threads;
    }
    table["audit"] = settings;
    const std::string stem = shard_text.empty() ? std::string("audit")
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
