// The audit table (audit/audit_table.hpp) and shard choice (audit/audit_shard.hpp) on fabricated report.json objects with
// known values. Does not include pipeline.hpp: this file compiles in seconds.
#include <catch2/catch.hpp>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <set>
#include <sstream>

#include "orbitforge/audit/audit_shard.hpp"
#include "orbitforge/audit/audit_table.hpp"

using namespace orbitforge;
using nlohmann::json;

namespace {

// A report.json shaped like stage_report's, with the numbers given.
json fake_report(double r0_a, double r1_a, double r0_gap_psnr, double r1_gap_psnr, double total) {
  json q = {{"R0",
             {{"supported", {{"psnr", 30.0}, {"ssim", 0.9}, {"views", 17}}},
              {"gap_heldout", {{"psnr", r0_gap_psnr}, {"ssim", 0.6}, {"views", 28}}}}},
            {"R1",
             {{"supported", {{"psnr", 28.0}, {"ssim", 0.85}, {"views", 17}}},
              {"gap_heldout", {{"psnr", r1_gap_psnr}, {"ssim", 0.8}, {"views", 28}}}}}};
  return {{"input", "fake"},
          {"stages", {{"orbit", 0.5}, {"g0", 40.0}, {"completion", 2.0}, {"g1", 50.0}, {"report", 3.0}}},
          {"total_seconds", total},
          {"coverage",
           {{"R0", {{"A", r0_a}, {"M", 1.0}, {"closed", false}}}, {"R1", {{"A", r1_a}, {"M", 0.95}, {"closed", r1_a > 330}}}}},
          {"diagnostics",
           {{"lookat_error_deg", 0.25}, {"height_std", 0.001}, {"circle_rmse", 0.002}, {"normal_rule", "look_down"},
            {"source_span_deg", 120.0}}},
          {"quality", q},
          {"completion", {{"loop_endpoint_l1", 4.5}, {"anchor_index_error", {{"mean", 1.5}, {"max", 3}}}}}};
}

const json& value(const json& table, const std::string& row, const std::string& key) {
  for (const auto& r : table.at("rows"))
    if (r.at("name") == row) return r.at("values").at(key);
  for (const auto& s : table.at("summary"))
    if (s.at("name") == row) return s.at("values").at(key);
  FAIL("no row " << row);
  static const json none;
  return none;
}

std::vector<std::string> lines_of(const std::string& text) {
  std::vector<std::string> out;
  std::istringstream in(text);
  for (std::string l; std::getline(in, l);) out.push_back(l);
  return out;
}

// Fields of one CSV line (RFC 4180 quoting, no embedded newlines).
std::vector<std::string> csv_fields(const std::string& line) {
  std::vector<std::string> f(1);
  bool quoted = false;
  for (std::size_t i = 0; i < line.size(); ++i) {
    const char c = line[i];
    if (quoted) {
      if (c == '"' && i + 1 < line.size() && line[i + 1] == '"') {
        f.back() += '"';
        ++i;
      } else if (c == '"') {
        quoted = false;
      } else {
        f.back() += c;
      }
    } else if (c == '"') {
      quoted = true;
    } else if (c == ',') {
      f.emplace_back();
    } else {
      f.back() += c;
    }
  }
  return f;
}

}  // namespace

TEST_CASE("parse_shard accepts i/n with 1 <= i <= n and rejects the rest", "[pipeline][audit]") {
  const AuditShard a = parse_shard("1/1");
  REQUIRE(a.index == 1);
  REQUIRE(a.count == 1);
  const AuditShard b = parse_shard("2/5");
  REQUIRE(b.index == 2);
  REQUIRE(b.count == 5);
  REQUIRE(parse_shard("5/5").index == 5);
  for (const char* bad : {"", "3", "0/3", "4/3", "a/b", "2/", "/3", "-1/3", "1/0", "1.5/3", " 1/3", "1/3/4", "+1/3"})
    REQUIRE_THROWS_AS(parse_shard(bad), Error);
  REQUIRE_THROWS_WITH(parse_shard("4/3"), Catch::Contains("4/3") && Catch::Contains("[1, n]"));
}

TEST_CASE("shards partition the inputs, whatever order they are given in", "[pipeline][audit]") {
  // Known split: sorted a b c d e, two shards -> a c e | b d.
  const std::vector<std::string> few = {"d", "b", "e", "a", "c"};
  REQUIRE(shard_inputs(few, {1, 2}) == std::vector<std::string>{"a", "c", "e"});
  REQUIRE(shard_inputs(few, {2, 2}) == std::vector<std::string>{"b", "d"});

  std::vector<std::string> inputs;
  for (int i = 0; i < 13; ++i) inputs.push_back("/data/v3d/video_" + std::to_string(i * 7 % 13));
  std::mt19937 rng(1234);
  for (int n = 1; n <= 6; ++n) {
    std::vector<std::string> shuffled = inputs;
    std::shuffle(shuffled.begin(), shuffled.end(), rng);
    std::multiset<std::string> seen;
    std::size_t largest = 0, smallest = inputs.size();
    for (int i = 1; i <= n; ++i) {
      const auto part = shard_inputs(shuffled, {i, n});
      REQUIRE(part == shard_inputs(inputs, {i, n}));  // order-independent
      largest = std::max(largest, part.size());
      smallest = std::min(smallest, part.size());
      seen.insert(part.begin(), part.end());
    }
    REQUIRE(seen.size() == inputs.size());
    for (const auto& in : inputs) REQUIRE(seen.count(in) == 1);
    REQUIRE(largest - smallest <= 1);  // round-robin: balanced
  }
  REQUIRE_THROWS_AS(shard_inputs(inputs, {0, 3}), Error);
  REQUIRE_THROWS_AS(shard_inputs(inputs, {4, 3}), Error);
}

TEST_CASE("quantiles interpolate linearly between order statistics", "[pipeline][audit]") {
  // Odd count: sorted 1 2 3 4 5; P90 at h = 3.6 -> 4.6.
  REQUIRE(audit_quantile({3, 1, 2, 5, 4}, 0.5) == Approx(3.0));
  REQUIRE(audit_quantile({3, 1, 2, 5, 4}, 0.9) == Approx(4.6));
  // Even count: sorted 10 20 30 40; median 25, P90 at h = 2.7 -> 37.
  REQUIRE(audit_quantile({40, 10, 30, 20}, 0.5) == Approx(25.0));
  REQUIRE(audit_quantile({40, 10, 30, 20}, 0.9) == Approx(37.0));
  REQUIRE(audit_quantile({7}, 0.5) == 7.0);
  REQUIRE(audit_quantile({7}, 0.9) == 7.0);
  REQUIRE(audit_quantile({2, 9}, 0.0) == 2.0);
  REQUIRE(audit_quantile({2, 9}, 1.0) == 9.0);
  REQUIRE_THROWS_AS(audit_quantile({}, 0.5), Error);
  REQUIRE_THROWS_AS(audit_quantile({1.0}, 1.5), Error);
}

TEST_CASE("audit table: per-input cells, gain, and summaries over the successful inputs", "[pipeline][audit]") {
  std::vector<AuditRow> rows;
  rows.push_back({"alpha", fake_report(120, 340, 18, 25, 100), "", ""});
  rows.push_back({"beta", fake_report(110, 350, 20, 24, 300), "", ""});
  rows.push_back({"gamma", fake_report(130, 320, 16, 26, 200), "", ""});
  rows.push_back({"delta", fake_report(125, 345, 19, 23, 400), "", ""});
  // Failed inputs have extreme numbers that would move every summary if counted.
  rows.push_back({"failed_one", fake_report(1000, 1000, 1000, -1000, 1e6), "orbit: too few cameras", ""});
  rows.push_back({"stopped_one", fake_report(1000, 1000, 1000, -1000, 1e6), "waiting for frames", "stopped"});
  const json t = audit_table(rows);

  REQUIRE(t.at("rows").size() == 6);
  REQUIRE(value(t, "alpha", "R1_A") == 340.0);
  REQUIRE(value(t, "gamma", "R1_closed") == false);
  REQUIRE(value(t, "beta", "R1_closed") == true);
  REQUIRE(value(t, "alpha", "normal_rule") == "look_down");
  REQUIRE(value(t, "alpha", "anchor_error_max") == 3);
  REQUIRE(value(t, "alpha", "gain_gap_psnr").get<double>() == Approx(7.0));
  REQUIRE(value(t, "beta", "gain_gap_psnr").get<double>() == Approx(4.0));
  REQUIRE(value(t, "gamma", "gain_gap_psnr").get<double>() == Approx(10.0));
  REQUIRE(value(t, "delta", "gain_gap_psnr").get<double>() == Approx(4.0));
  REQUIRE(value(t, "alpha", "seconds_g1") == 50.0);
  REQUIRE(value(t, "alpha", "radius").is_null());  // no orbit object in this report

  // Failed rows: listed with their error and status, no cells.
  REQUIRE(t["rows"][4]["status"] == "failed");
  REQUIRE(t["rows"][4]["error"] == "orbit: too few cameras");
  REQUIRE(t["rows"][4]["values"]["R0_A"].is_null());
  REQUIRE(t["rows"][5]["status"] == "stopped");
  REQUIRE(t["rows"][0]["status"] == "ok");

  // Even count (4 successful inputs). R0 A: 110 120 125 130 -> median 122.5, P90 h = 2.7 -> 128.5.
  REQUIRE(value(t, "median", "R0_A").get<double>() == Approx(122.5));
  REQUIRE(value(t, "P90", "R0_A").get<double>() == Approx(128.5));
  // Total seconds 100 200 300 400 -> 250, 370.
  REQUIRE(value(t, "median", "total_seconds").get<double>() == Approx(250.0));
  REQUIRE(value(t, "P90", "total_seconds").get<double>() == Approx(370.0));
  // Gain is summarised per input: 4 4 7 10 -> median 5.5, P90 h = 2.7 -> 9.1
  // (not the difference of the median PSNRs: 24.5 - 18.5 = 6).
  REQUIRE(value(t, "median", "gain_gap_psnr").get<double>() == Approx(5.5));
  REQUIRE(value(t, "P90", "gain_gap_psnr").get<double>() == Approx(9.1));
  REQUIRE(t["summary"][0]["counts"]["R0_A"] == 4);
  // Booleans and strings have no median.
  REQUIRE(value(t, "median", "R1_closed").is_null());
  REQUIRE(value(t, "median", "normal_rule").is_null());

  // Odd count: drop delta. R0 A: 110 120 130 -> 120, P90 h = 1.8 -> 128.
  rows.erase(rows.begin() + 3);
  const json t3 = audit_table(rows);
  REQUIRE(value(t3, "median", "R0_A").get<double>() == Approx(120.0));
  REQUIRE(value(t3, "P90", "R0_A").get<double>() == Approx(128.0));
}

TEST_CASE("audit table tolerates missing keys, odd types and unmeasured quality", "[pipeline][audit]") {
  json partial = fake_report(120, 340, 18, 25, 100);
  partial.erase("stages");
  partial["coverage"]["R1"] = json::array();            // wrong type
  partial["diagnostics"]["lookat_error_deg"] = "oops";  // a string where a number belongs: shown as is
  partial["quality"]["R0"]["gap_heldout"]["views"] = 0;  // mean over no views is not a measurement
  // static_proxy.json's layout, with fixed_slice and frame_varying absent.
  partial["static_proxy"] = {{"views_scored", 12}, {"variants", {{"median", {{"adjacent_l1", 1.25}, {"loop_l1", 2.5}}}}}};
  std::vector<AuditRow> rows = {{"partial", partial, "", ""},
                                {"empty", json::object(), "", ""},
                                {"null", json(), "", ""},
                                {"full", fake_report(100, 300, 20, 22, 50), "", ""},
                                {"flat_proxy", json::object(), "", ""}};
  // The layout without the "variants" level is read too.
  rows.back().report["static_proxy"] = {{"fixed_slice", {{"loop_l1", 7.5}}}};
  rows.back().report["stages"] = {{"static_proxy", 12.0}};
  json t;
  REQUIRE_NOTHROW(t = audit_table(rows));
  REQUIRE(value(t, "partial", "seconds_g0").is_null());
  REQUIRE(value(t, "partial", "R1_A").is_null());
  REQUIRE(value(t, "partial", "R0_gap_psnr").is_null());
  REQUIRE(value(t, "partial", "gain_gap_psnr").is_null());
  REQUIRE(value(t, "partial", "R1_gap_psnr") == 25.0);
  REQUIRE(value(t, "partial", "static_median_adjacent_l1") == 1.25);
  REQUIRE(value(t, "partial", "static_median_adjacent_l1_p95").is_null());
  REQUIRE(value(t, "partial", "static_fixed_slice_loop_l1").is_null());
  REQUIRE(value(t, "flat_proxy", "static_fixed_slice_loop_l1") == 7.5);
  REQUIRE(value(t, "flat_proxy", "seconds_static_proxy") == 12.0);
  REQUIRE(value(t, "partial", "seconds_static_proxy").is_null());
  REQUIRE(value(t, "empty", "R0_A").is_null());
  REQUIRE(value(t, "null", "total_seconds").is_null());
  // Summaries only over inputs that have the value: R1 A only from "full".
  REQUIRE(value(t, "median", "R1_A") == 300.0);
  REQUIRE(t["summary"][0]["counts"]["R1_A"] == 1);
  REQUIRE(value(t, "median", "R0_A").get<double>() == Approx(110.0));
  REQUIRE(t["summary"][0]["counts"]["seconds_g0"] == 1);
  REQUIRE(value(t, "median", "static_frame_varying_loop_l1").is_null());
  REQUIRE(t["summary"][0]["counts"]["static_frame_varying_loop_l1"] == 0);
  REQUIRE(value(t, "median", "static_median_loop_l1") == 2.5);

  const std::string md = audit_markdown(t);
  REQUIRE(md.find("Static proxy") != std::string::npos);
  REQUIRE_NOTHROW(audit_csv(t));
  // View-fitted scores get their own section when a run has them.
  json fitted = fake_report(120, 340, 18, 25, 100);
  fitted["quality"]["R1"]["gap_heldout_view_fitted"] = {
      {"psnr", 26.5}, {"ssim", 0.8}, {"views", 28}, {"view_fit", {{"turn_mean_deg", 0.4}}}};
  const json tf = audit_table({{"fitted", fitted, "", ""}});
  REQUIRE(value(tf, "fitted", "R1_gap_fitted_psnr") == 26.5);
  REQUIRE(value(tf, "fitted", "R1_gap_turn_mean") == 0.4);
  REQUIRE_THAT(audit_markdown(tf), Catch::Contains("## Quality, views fitted"));
  // Nothing at all: empty tables, no crash.
  const json none = audit_table({});
  REQUIRE(none["rows"].empty());
  REQUIRE(value(none, "median", "R0_A").is_null());
  REQUIRE_NOTHROW(audit_markdown(none));
  REQUIRE(lines_of(audit_csv(none)).size() == 3);  // header + median + P90
}

TEST_CASE("audit markdown: a row per input, failures with their error, '-' for missing", "[pipeline][audit]") {
  json no_time = fake_report(100, 340, 18, 25, 100);
  no_time.erase("total_seconds");
  std::vector<AuditRow> rows = {{"cool_teddy", fake_report(121, 339, 19.72, 24.88, 125.9), "", ""},
                                {"doll", no_time, "", ""},
                                {"robot", json(), "robot/sparse: missing | broken\nmodel", ""}};
  const json t = audit_table(rows);
  const std::string md = audit_markdown(t);
  const auto lines = lines_of(md);
  auto count_prefix = [&](const std::string& prefix) {
    return std::count_if(lines.begin(), lines.end(), [&](const std::string& l) { return l.rfind(prefix, 0) == 0; });
  };
  // Inputs table + one row in each of the seven sections (no static proxy here).
  REQUIRE(count_prefix("| cool_teddy |") == 8);
  REQUIRE(count_prefix("| doll |") == 8);
  REQUIRE(count_prefix("| robot | failed |") == 1);
  REQUIRE(count_prefix("| robot |") == 1);  // failed: not in the metric tables
  REQUIRE(count_prefix("| **median** |") == 7);
  REQUIRE(count_prefix("| **P90** |") == 7);
  REQUIRE(md.find("Static proxy") == std::string::npos);
  REQUIRE(md.find("views fitted") == std::string::npos);  // opt-in scores: no empty section
  REQUIRE(md.find("missing \\| broken model") != std::string::npos);  // escaped, one line
  REQUIRE(md.find("2 of 3 inputs succeeded") != std::string::npos);
  // Values with their column's digits; the missing total is "-".
  REQUIRE(md.find("| cool_teddy | 121.0 | 339.0 | 0.950 | yes |") != std::string::npos);
  bool doll_total_missing = false;
  for (const auto& l : lines)
    if (l.rfind("| doll | 0.5 |", 0) == 0) doll_total_missing = l.size() > 4 && l.substr(l.size() - 4) == " - |";
  REQUIRE(doll_total_missing);
  // Every table row has as many cells as its header.
  std::size_t header_cells = 0;
  for (const auto& l : lines) {
    if (l.rfind("| input |", 0) == 0) header_cells = std::count(l.begin(), l.end(), '|');
    else if (l.rfind("| ", 0) == 0) {
      std::size_t bars = 0;
      for (std::size_t i = 0; i < l.size(); ++i)
        if (l[i] == '|' && (i == 0 || l[i - 1] != '\\')) ++bars;
      REQUIRE(bars == header_cells);
    }
  }
}

TEST_CASE("audit csv: header, a line per input, summaries, quoting, empty for missing", "[pipeline][audit]") {
  json no_time = fake_report(100, 340, 18, 25, 100);
  no_time.erase("total_seconds");
  const json t = audit_table({{"a", fake_report(121, 339, 19.5, 24.5, 125.5), "", ""},
                              {"b", no_time, "", ""},
                              {"c", json(), "bad \"input\", see log", ""}});
  const auto lines = lines_of(audit_csv(t));
  REQUIRE(lines.size() == 1 + 3 + 2);
  const auto header = csv_fields(lines[0]);
  REQUIRE(header[0] == "name");
  REQUIRE(header[1] == "status");
  REQUIRE(header[2] == "error");
  REQUIRE(header.size() == 3 + t["columns"].size());
  auto column = [&](const std::string& key) {
    return std::size_t(std::find(header.begin(), header.end(), key) - header.begin());
  };
  for (const auto& l : lines) REQUIRE(csv_fields(l).size() == header.size());
  const auto a = csv_fields(lines[1]), b = csv_fields(lines[2]), c = csv_fields(lines[3]);
  REQUIRE(a[0] == "a");
  REQUIRE(a[1] == "ok");
  REQUIRE(std::stod(a[column("R0_A")]) == 121.0);
  REQUIRE(std::stod(a[column("total_seconds")]) == 125.5);
  REQUIRE(a[column("R1_closed")] == "true");
  REQUIRE(std::stod(a[column("gain_gap_psnr")]) == Approx(5.0));
  REQUIRE(b[column("total_seconds")].empty());
  REQUIRE(c[1] == "failed");
  REQUIRE(c[2] == "bad \"input\", see log");
  REQUIRE(c[column("R0_A")].empty());
  REQUIRE(csv_fields(lines[4])[0] == "median");
  REQUIRE(csv_fields(lines[4])[1] == "summary");
  REQUIRE(std::stod(csv_fields(lines[4])[column("R0_A")]) == Approx(110.5));
  REQUIRE(std::stod(csv_fields(lines[5])[column("total_seconds")]) == Approx(125.5));
}

TEST_CASE("read_audit_row reads report.json and the orbit radius; missing files make failed rows",
          "[pipeline][audit]") {
  namespace fs = std::filesystem;
  const fs::path root = fs::temp_directory_path() / "orbitforge_test_audit";
  fs::remove_all(root);
  fs::create_directories(root / "good");
  fs::create_directories(root / "broken");
  fs::create_directories(root / "empty");
  write_file_atomic((root / "good" / "report.json").string(), fake_report(120, 340, 18, 25, 100).dump(1));
  write_file_atomic((root / "good" / "orbit.json").string(), json({{"orbit", {{"radius", 2.75}}}}).dump());
  write_file_atomic((root / "broken" / "report.json").string(), "{\"coverage\": [1, 2");

  const AuditRow good = read_audit_row("good", (root / "good").string());
  REQUIRE(good.error.empty());
  const AuditRow broken = read_audit_row("broken", (root / "broken").string());
  REQUIRE_THAT(broken.error, Catch::Contains("report.json") && Catch::Contains("not valid JSON"));
  const AuditRow empty = read_audit_row("empty", (root / "empty").string());
  REQUIRE_THAT(empty.error, Catch::Contains("report.json") && Catch::Contains("does not exist"));

  const json t = audit_table({good, broken, empty});
  REQUIRE(value(t, "good", "radius") == 2.75);
  REQUIRE(value(t, "good", "R1_A") == 340.0);
  REQUIRE(t["rows"][1]["status"] == "failed");
  REQUIRE(t["rows"][2]["status"] == "failed");
  REQUIRE(value(t, "median", "radius") == 2.75);
  fs::remove_all(root);
}

namespace {

// A fixed environment for choose_shard: no setenv, so no races with other tests.
EnvLookup env_of(std::map<std::string, std::string> vars) {
  return [vars = std::move(vars)](const std::string& name) -> std::optional<std::string> {
    const auto it = vars.find(name);
    if (it == vars.end()) return std::nullopt;
    return it->second;
  };
}

void require_shard(const AuditShardChoice& c, int index, int count, const std::string& source) {
  INFO(c.source << " " << c.shard.index << "/" << c.shard.count << " (" << c.detail << ")");
  REQUIRE(c.shard.index == index);
  REQUIRE(c.shard.count == count);
  REQUIRE(c.source == source);
}

}  // namespace

TEST_CASE("choose_shard: no flag and no scheduler is the whole list", "[pipeline][audit]") {
  require_shard(choose_shard("", "", env_of({})), 1, 1, "none");
  // A plain (non-array) Slurm job is not sharded.
  require_shard(choose_shard("", "", env_of({{"SLURM_JOB_ID", "77"}})), 1, 1, "none");
  REQUIRE_THROWS_WITH(choose_shard("", "4", env_of({})), Catch::Contains("JOB_COMPLETION_INDEX"));
}

TEST_CASE("choose_shard: Slurm array tasks, numbered from 0 or 1 or in steps", "[pipeline][audit]") {
  // --array=0-3 and --array=1-4 give the same four shards.
  for (int min : {0, 1}) {
    for (int k = 0; k < 4; ++k) {
      const auto env = env_of({{"SLURM_ARRAY_TASK_ID", std::to_string(min + k)},
                               {"SLURM_ARRAY_TASK_MIN", std::to_string(min)},
                               {"SLURM_ARRAY_TASK_MAX", std::to_string(min + 3)},
                               {"SLURM_ARRAY_TASK_COUNT", "4"}});
      const AuditShardChoice c = choose_shard("", "", env);
      require_shard(c, k + 1, 4, "slurm");
      REQUIRE_THAT(c.detail, Catch::Contains("SLURM_ARRAY_TASK_ID=" + std::to_string(min + k)));
    }
  }
  // --array=3-9:3: tasks 3, 6, 9.
  const auto stepped = [](const std::string& id) {
    return env_of({{"SLURM_ARRAY_TASK_ID", id},
                   {"SLURM_ARRAY_TASK_MIN", "3"},
                   {"SLURM_ARRAY_TASK_MAX", "9"},
                   {"SLURM_ARRAY_TASK_COUNT", "3"},
                   {"SLURM_ARRAY_TASK_STEP", "3"}});
  };
  require_shard(choose_shard("", "", stepped("6")), 2, 3, "slurm");
  require_shard(choose_shard("", "", stepped("9")), 3, 3, "slurm");
  REQUIRE_THROWS_WITH(choose_shard("", "", stepped("7")), Catch::Contains("SLURM_ARRAY_TASK_ID 7"));
  // A list with gaps (--array=1,3,7): Slurm sets STEP=1, MIN=1, MAX=7, COUNT=3;
  // refused in every task, also those whose ID would fit.
  for (const char* id : {"1", "3", "7"})
    REQUIRE_THROWS_WITH(choose_shard("", "", env_of({{"SLURM_ARRAY_TASK_ID", id},
                                                     {"SLURM_ARRAY_TASK_MIN", "1"},
                                                     {"SLURM_ARRAY_TASK_MAX", "7"},
                                                     {"SLURM_ARRAY_TASK_COUNT", "3"},
                                                     {"SLURM_ARRAY_TASK_STEP", "1"}})),
                        Catch::Contains("SLURM_ARRAY_TASK_MAX"));
  // A contiguous list (--array=4,5,6) is a range.
  require_shard(choose_shard("", "", env_of({{"SLURM_ARRAY_TASK_ID", "5"},
                                             {"SLURM_ARRAY_TASK_MIN", "4"},
                                             {"SLURM_ARRAY_TASK_MAX", "6"},
                                             {"SLURM_ARRAY_TASK_COUNT", "3"},
                                             {"SLURM_ARRAY_TASK_STEP", "1"}})),
                2, 3, "slurm");
  // A matching --shard-count is accepted, a different one refused.
  const auto task2 = env_of({{"SLURM_ARRAY_TASK_ID", "2"}, {"SLURM_ARRAY_TASK_MIN", "1"}, {"SLURM_ARRAY_TASK_COUNT", "2"}});
  require_shard(choose_shard("", "2", task2), 2, 2, "slurm");
  REQUIRE_THROWS_WITH(choose_shard("", "3", task2), Catch::Contains("SLURM_ARRAY_TASK_COUNT"));
}

TEST_CASE("choose_shard: Kubernetes Indexed Jobs need --shard-count", "[pipeline][audit]") {
  require_shard(choose_shard("", "3", env_of({{"JOB_COMPLETION_INDEX", "0"}})), 1, 3, "kubernetes");
  require_shard(choose_shard("", "3", env_of({{"JOB_COMPLETION_INDEX", "2"}})), 3, 3, "kubernetes");
  REQUIRE_THROWS_WITH(choose_shard("", "", env_of({{"JOB_COMPLETION_INDEX", "2"}})),
                      Catch::Contains("JOB_COMPLETION_INDEX") && Catch::Contains("--shard-count"));
  REQUIRE_THROWS_WITH(choose_shard("", "3", env_of({{"JOB_COMPLETION_INDEX", "3"}})),
                      Catch::Contains("JOB_COMPLETION_INDEX 3"));
}

TEST_CASE("choose_shard: an explicit --shard wins over the environment", "[pipeline][audit]") {
  const auto both = env_of({{"SLURM_ARRAY_TASK_ID", "0"},
                            {"SLURM_ARRAY_TASK_MIN", "0"},
                            {"SLURM_ARRAY_TASK_COUNT", "4"},
                            {"JOB_COMPLETION_INDEX", "1"}});
  const AuditShardChoice c = choose_shard("3/5", "", both);
  require_shard(c, 3, 5, "flag");
  REQUIRE(c.detail == "--shard 3/5");
  // Even over malformed variables: the flag is the user's answer.
  require_shard(choose_shard("1/2", "", env_of({{"SLURM_ARRAY_TASK_ID", "x"}})), 1, 2, "flag");
  REQUIRE_THROWS_WITH(choose_shard("1/2", "3", env_of({})), Catch::Contains("--shard-count 3"));
  REQUIRE_THROWS_AS(choose_shard("0/2", "", env_of({})), Error);
}

TEST_CASE("choose_shard: malformed or inconsistent variables are named", "[pipeline][audit]") {
  using Vars = std::map<std::string, std::string>;
  const Vars good = {{"SLURM_ARRAY_TASK_ID", "1"}, {"SLURM_ARRAY_TASK_MIN", "0"}, {"SLURM_ARRAY_TASK_COUNT", "2"}};
  const std::vector<std::pair<std::string, std::string>> bad = {
      {"SLURM_ARRAY_TASK_ID", "one"},    {"SLURM_ARRAY_TASK_ID", "-1"},     {"SLURM_ARRAY_TASK_ID", ""},
      {"SLURM_ARRAY_TASK_ID", " 1"},     {"SLURM_ARRAY_TASK_MIN", "1.0"},   {"SLURM_ARRAY_TASK_COUNT", "0"},
      {"SLURM_ARRAY_TASK_COUNT", "2x"},  {"SLURM_ARRAY_TASK_STEP", "0"},    {"SLURM_ARRAY_TASK_ID", "99999999999999999999"}};
  for (const auto& [name, text] : bad) {
    Vars v = good;
    v[name] = text;
    INFO(name << "='" << text << "'");
    REQUIRE_THROWS_WITH(choose_shard("", "", env_of(v)), Catch::Contains(name));
  }
  for (const char* missing : {"SLURM_ARRAY_TASK_MIN", "SLURM_ARRAY_TASK_COUNT"}) {
    Vars v = good;
    v.erase(missing);
    REQUIRE_THROWS_WITH(choose_shard("", "", env_of(v)), Catch::Contains(missing));
  }
  // ID below MIN, ID past the last task.
  REQUIRE_THROWS_WITH(choose_shard("", "", env_of({{"SLURM_ARRAY_TASK_ID", "0"},
                                                   {"SLURM_ARRAY_TASK_MIN", "1"},
                                                   {"SLURM_ARRAY_TASK_COUNT", "2"}})),
                      Catch::Contains("SLURM_ARRAY_TASK_MIN"));
  REQUIRE_THROWS_WITH(choose_shard("", "", env_of({{"SLURM_ARRAY_TASK_ID", "2"},
                                                   {"SLURM_ARRAY_TASK_MIN", "0"},
                                                   {"SLURM_ARRAY_TASK_COUNT", "2"}})),
                      Catch::Contains("SLURM_ARRAY_TASK_ID 2"));
  Vars both = good;
  both["JOB_COMPLETION_INDEX"] = "0";
  REQUIRE_THROWS_WITH(choose_shard("", "2", env_of(both)),
                      Catch::Contains("SLURM_ARRAY_TASK_ID") && Catch::Contains("JOB_COMPLETION_INDEX"));
  for (const char* text : {"", "-1", "a", "1e3"})
    REQUIRE_THROWS_WITH(choose_shard("", "3", env_of({{"JOB_COMPLETION_INDEX", text}})),
                        Catch::Contains("JOB_COMPLETION_INDEX"));
  REQUIRE_THROWS_WITH(choose_shard("", "0", env_of({{"JOB_COMPLETION_INDEX", "0"}})),
                      Catch::Contains("--shard-count"));
}

TEST_CASE("audit markdown names the shard's source", "[pipeline][audit]") {
  json t = audit_table({});
  REQUIRE_THAT(audit_markdown(t), !Catch::Contains("Shard "));
  t["audit"] = {{"shard", "2/4"}, {"shard_source", "slurm"}, {"shard_detail", "SLURM_ARRAY_TASK_ID=1"}};
  REQUIRE_THAT(audit_markdown(t), Catch::Contains("Shard 2/4 from slurm (SLURM_ARRAY_TASK_ID=1)"));
}
