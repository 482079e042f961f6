#pragma once
// The audit over many inputs: shard selection and one table of every input's
// report.json (coverage, orbit diagnostics, support-stratified quality,
// completion metrics, stage times, static-proxy flicker when present: report.json's
// "static_proxy" is static_proxy.json, {"variants": {"frame_varying" | "fixed_slice" |
// "median": {"adjacent_l1", "adjacent_l1_p95", "loop_l1"}}}; the same without the
// "variants" level is read too), with
// median and P90 rows, as JSON, Markdown and CSV.
//
// Aggregation only: this header does not run the pipeline (examples/audit.cpp
// does), so it stays cheap to compile (nlohmann json and std).
//
// Summary rows: over the inputs that succeeded and have the value. Quantile q of
// n sorted values x_0..x_{n-1}: h = (n-1) q, x_floor(h) + (h - floor(h)) (x_ceil(h) -
// x_floor(h)) (linear interpolation between order statistics, numpy's default);
// the median is q = 0.5 (mean of the middle two for even n), P90 is q = 0.9.
// Derived columns (the gain) are computed per input, then summarised.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/io/atomic_file.hpp"

namespace orbitforge {

// Shard i of n (1-based), from "i/n".
struct AuditShard {
  int index = 1, count = 1;
};

namespace audit_shard_detail {

// A decimal integer in [lo, hi] with nothing else around it (no sign, no
// spaces): `what` names it in the message.
inline long parse_count(const std::string& s, long lo, long hi, const std::string& what) {
  std::size_t used = 0;
  long v = 0;
  try {
    v = std::stol(s, &used);
  } catch (...) {
    used = 0;
  }
  ensure(!s.empty() && used == s.size() && s.find_first_not_of("0123456789") == std::string::npos && v >= lo &&
             v <= hi,
         what, " must be an integer in [", lo, ", ", hi, "], got '", s, "'");
  return v;
}

constexpr long kMaxShards = 100000;
constexpr long kMaxTaskId = 100000000;  // above Slurm's largest MaxArraySize (4000001)

}  // namespace audit_shard_detail

inline AuditShard parse_shard(const std::string& text) {
  using audit_shard_detail::parse_count;
  const std::size_t slash = text.find('/');
  ensure(slash != std::string::npos, "shard '", text, "': expected i/n (for example 2/5)");
  const std::string where = "shard '" + text + "': ";
  AuditShard s;
  s.index = int(parse_count(text.substr(0, slash), 1, audit_shard_detail::kMaxShards, where + "i"));
  s.count = int(parse_count(text.substr(slash + 1), 1, audit_shard_detail::kMaxShards, where + "n"));
  ensure(s.index <= s.count, "shard '", text, "': i must lie in [1, n]");
  return s;
}

// The shard and where it came from: "none" (the whole list), "flag" (--shard),
// "slurm" (an array job's task) or "kubernetes" (an Indexed Job's completion).
struct AuditShardChoice {
  AuditShard shard;
  std::string source = "none";
  std::string detail;  // the values it was computed from, for the report
};

// An environment variable's value, or nullopt when unset. A parameter rather than
// std::getenv so tests need no setenv (not thread-safe, and global).
using EnvLookup = std::function<std::optional<std::string>(const std::string&)>;

// The shard of this process: `flag_shard` (--shard i/n) when given, else a
// Slurm array task (SLURM_ARRAY_TASK_ID, _MIN, _COUNT and, for --array=A-B:S,
// _STEP: i = (ID - MIN) / STEP + 1, n = COUNT, so --array=0-3 and 1-4 give the
// same shards), else a Kubernetes Indexed Job's JOB_COMPLETION_INDEX (0-based,
// i = index + 1) with n = `shard_count` (--shard-count N: the Job's completions,
// which Kubernetes does not export). Empty strings mean "not given". Throws
// Error naming the variable when a value is malformed or the values disagree;
// a list array with gaps (--array=1,3,7) has no contiguous numbering and is
// refused.
inline AuditShardChoice choose_shard(const std::string& flag_shard, const std::string& shard_count,
                                     const EnvLookup& env) {
  using audit_shard_detail::kMaxShards;
  using audit_shard_detail::kMaxTaskId;
  using audit_shard_detail::parse_count;
  AuditShardChoice c;
  const long given_count = shard_count.empty() ? 0 : parse_count(shard_count, 1, kMaxShards, "--shard-count");
  auto count_agrees = [&](int n, const std::string& from) {
    ensure(given_count == 0 || given_count == n, "--shard-count ", given_count, " disagrees with ", from, " (", n,
           " shards)");
  };
  if (!flag_shard.empty()) {
    c.shard = parse_shard(flag_shard);
    count_agrees(c.shard.count, "--shard " + flag_shard);
    c.source = "flag";
    c.detail = "--shard " + flag_shard;
    return c;
  }
  // Set but empty counts as malformed: a template that forgot to fill it in.
  auto get = [&](const std::string& name) -> std::optional<std::string> {
    std::optional<std::string> v = env(name);
    if (v) ensure(!v->empty(), name, " is set but empty");
    return v;
  };
  const auto slurm_id = get("SLURM_ARRAY_TASK_ID");
  const auto k8s_index = get("JOB_COMPLETION_INDEX");
  if (slurm_id && k8s_index)
    fail("both SLURM_ARRAY_TASK_ID (", *slurm_id, ") and JOB_COMPLETION_INDEX (", *k8s_index,
         ") are set: give --shard i/n to say which applies");
  if (slurm_id) {
    auto need = [&](const std::string& name) {
      const auto v = get(name);
      ensure(v.has_value(), "SLURM_ARRAY_TASK_ID is set (", *slurm_id, ") but ", name,
             " is not: not a Slurm array task? (give --shard i/n)");
      return *v;
    };
    const std::string count_text = need("SLURM_ARRAY_TASK_COUNT"), min_text = need("SLURM_ARRAY_TASK_MIN");
    const long id = parse_count(*slurm_id, 0, kMaxTaskId, "SLURM_ARRAY_TASK_ID");
    const long count = parse_count(count_text, 1, kMaxShards, "SLURM_ARRAY_TASK_COUNT");
    const long min = parse_count(min_text, 0, kMaxTaskId, "SLURM_ARRAY_TASK_MIN");
    const auto step_text = get("SLURM_ARRAY_TASK_STEP");
    const long step = step_text ? parse_count(*step_text, 1, kMaxTaskId, "SLURM_ARRAY_TASK_STEP") : 1;
    c.detail = "SLURM_ARRAY_TASK_ID=" + *slurm_id + " SLURM_ARRAY_TASK_MIN=" + min_text +
               " SLURM_ARRAY_TASK_COUNT=" + count_text + (step_text ? " SLURM_ARRAY_TASK_STEP=" + *step_text : "");
    // A list (--array=1,3,7) still gets STEP=1 from Slurm: MAX shows the gaps, so
    // every task refuses it, not only the ones past COUNT.
    if (const auto max_text = get("SLURM_ARRAY_TASK_MAX")) {
      const long max = parse_count(*max_text, 0, kMaxTaskId, "SLURM_ARRAY_TASK_MAX");
      ensure(max == min + (count - 1) * step, "SLURM_ARRAY_TASK_MAX ", max, " is not SLURM_ARRAY_TASK_MIN ", min,
             " + (SLURM_ARRAY_TASK_COUNT ", count, " - 1) x STEP ", step,
             ": the array is a list with gaps; use --array=A-B or A-B:S");
    }
    ensure(id >= min, "SLURM_ARRAY_TASK_ID ", id, " is below SLURM_ARRAY_TASK_MIN ", min);
    ensure((id - min) % step == 0 && (id - min) / step < count, "SLURM_ARRAY_TASK_ID ", id,
           " is not one of SLURM_ARRAY_TASK_COUNT ", count, " tasks from SLURM_ARRAY_TASK_MIN ", min, " in steps of ",
           step, " (", c.detail, "); use --array=A-B or A-B:S, not a list");
    c.shard = {int((id - min) / step + 1), int(count)};
    count_agrees(c.shard.count, "SLURM_ARRAY_TASK_COUNT");
    c.source = "slurm";
    return c;
  }
  if (k8s_index) {
    const long index = parse_count(*k8s_index, 0, kMaxShards - 1, "JOB_COMPLETION_INDEX");
    ensure(given_count > 0, "JOB_COMPLETION_INDEX is set (", index,
           ") but --shard-count N is not given (N: the Indexed Job's completions)");
    ensure(index < given_count, "JOB_COMPLETION_INDEX ", index, " must lie in [0, --shard-count - 1 = ",
           given_count - 1, "]");
    c.shard = {int(index + 1), int(given_count)};
    c.source = "kubernetes";
    c.detail = "JOB_COMPLETION_INDEX=" + *k8s_index + " --shard-count " + shard_count;
    return c;
  }
  ensure(given_count == 0, "--shard-count ", given_count,
         " needs JOB_COMPLETION_INDEX (a Kubernetes Indexed Job); outside one give --shard i/n");
  return c;
}

// The inputs of one shard: sorted by path, input k (0-based, after sorting) goes to
// shard k % n + 1, so the shards partition the inputs whatever order they came in.
inline std::vector<std::string> shard_inputs(std::vector<std::string> inputs, AuditShard shard) {
  ensure(shard.count >= 1 && shard.index >= 1 && shard.index <= shard.count, "shard ", shard.index, "/",
         shard.count, ": i must lie in [1, n]");
  std::sort(inputs.begin(), inputs.end());
  std::vector<std::string> mine;
  for (std::size_t k = 0; k < inputs.size(); ++k)
    if (int(k % std::size_t(shard.count)) + 1 == shard.index) mine.push_back(inputs[k]);
  return mine;
}

// One input: its name, its report.json (with orbit.json's "orbit" object merged in
// under "orbit" when available) and, when it failed, why (non-empty).
struct AuditRow {
  std::string name;
  nlohmann::json report;
  std::string error;
  std::string status;  // empty: "ok" or "failed" from `error`; anything but "ok" (e.g. "stopped") counts as failed
};

namespace audit_detail {

// One column of the table.
struct Column {
  const char* key;      // JSON / CSV name
  const char* title;    // Markdown header
  const char* section;  // Markdown table it belongs to
  const char* pointer;  // JSON pointer into the report ("" for derived columns)
  int digits;           // Markdown decimals
  const char* alt = "";  // where older or other report layouts keep it (tried when `pointer` is missing)
};

inline const std::vector<Column>& columns() {
  static const std::vector<Column> c = {
      {"R0_A", "R0 A (deg)", "Coverage", "/coverage/R0/A", 1},
      {"R1_A", "R1 A (deg)", "Coverage", "/coverage/R1/A", 1},
      {"R1_M", "R1 M", "Coverage", "/coverage/R1/M", 3},
      {"R1_closed", "R1 closed", "Coverage", "/coverage/R1/closed", 0},
      {"lookat_error_deg", "look-at error (deg)", "Orbit diagnostics", "/diagnostics/lookat_error_deg", 3},
      {"radius", "radius", "Orbit diagnostics", "/orbit/radius", 4},
      {"plane_rms", "plane RMS (height std)", "Orbit diagnostics", "/diagnostics/height_std", 4},
      {"circle_rmse", "circle RMSE", "Orbit diagnostics", "/diagnostics/circle_rmse", 4},
      {"normal_rule", "normal rule", "Orbit diagnostics", "/diagnostics/normal_rule", 0},
      {"source_span_deg", "source span (deg)", "Orbit diagnostics", "/diagnostics/source_span_deg", 1},
      {"camera_path", "cameras", "Cameras", "/cameras/path", 0},
      {"orbit_check_ok", "orbit check passed", "Cameras", "/orbit_check/ok", 0},
      {"speed_trend", "speed trend (2nd / 1st half)", "Cameras", "/orbit_check/trend_halves", 3},
      {"arc_user", "source arc, estimated (deg)", "Cameras", "/cameras/reference/source_arc_deg/user", 1},
      {"arc_reference", "source arc, reference (deg)", "Cameras", "/cameras/reference/source_arc_deg/reference", 1},
      {"focal_user", "focal, estimated (px)", "Cameras", "/cameras/reference/focal_px/user", 1},
      {"focal_reference", "focal, reference (px)", "Cameras", "/cameras/reference/focal_px/reference", 1},
      {"reference_centre_residual", "alignment centre residual (of spread)", "Cameras",
       "/cameras/reference/alignment/centre_rms_relative", 4},
      {"reference_rotation_max", "alignment rotation residual max (deg)", "Cameras",
       "/cameras/reference/alignment/rotation_max_deg", 2},
      {"gap_azimuth_error_mean", "gap azimuth error mean (deg)", "Cameras",
       "/cameras/reference/gap_azimuth_error_deg/mean_abs", 2},
      {"gap_azimuth_error_max", "gap azimuth error max (deg)", "Cameras",
       "/cameras/reference/gap_azimuth_error_deg/max_abs", 2},
      {"R0_supported_psnr", "R0 sup PSNR (withheld)", "Quality", "/quality/R0/supported_heldout/psnr", 2},
      {"R1_supported_psnr", "R1 sup PSNR (withheld)", "Quality", "/quality/R1/supported_heldout/psnr", 2},
      {"R0_supported_ref_psnr", "R0 sup PSNR (withheld, at the reference's cameras)", "Quality",
       "/quality/R0/supported_heldout_at_reference/psnr", 2},
      {"R1_supported_ref_psnr", "R1 sup PSNR (withheld, at the reference's cameras)", "Quality",
       "/quality/R1/supported_heldout_at_reference/psnr", 2},
      {"R1_paper_supported_psnr", "R1 paper-data sup PSNR (withheld)", "Quality",
       "/quality/R1_paper/supported_heldout/psnr", 2},
      {"bound_supported_psnr", "bound sup PSNR (withheld)", "Quality", "/quality/bound/supported_heldout/psnr", 2},
      {"R0_gap_psnr", "R0 gap PSNR", "Quality", "/quality/R0/gap_heldout/psnr", 2},
      {"R1_gap_psnr", "R1 gap PSNR", "Quality", "/quality/R1/gap_heldout/psnr", 2},
      {"R1_paper_gap_psnr", "R1 paper-data gap PSNR", "Quality", "/quality/R1_paper/gap_heldout/psnr", 2},
      {"bound_gap_psnr", "bound gap PSNR", "Quality", "/quality/bound/gap_heldout/psnr", 2},
      {"gain_gap_psnr", "gain (R1 - R0 gap PSNR)", "Quality", "", 2},
      {"R0_gap_ssim", "R0 gap SSIM", "Quality", "/quality/R0/gap_heldout/ssim", 3},
      {"R1_gap_ssim", "R1 gap SSIM", "Quality", "/quality/R1/gap_heldout/ssim", 3},
      {"R0_train_psnr", "R0 sup PSNR (training frames)", "Fit to training frames",
       "/quality/R0/supported_train/psnr", 2},
      {"R1_train_psnr", "R1 sup PSNR (training frames)", "Fit to training frames",
       "/quality/R1/supported_train/psnr", 2},
      {"R1_paper_train_psnr", "R1 paper-data sup PSNR (training frames)", "Fit to training frames",
       "/quality/R1_paper/supported_train/psnr", 2},
      {"bound_train_psnr", "bound sup PSNR (training frames)", "Fit to training frames",
       "/quality/bound/supported_train/psnr", 2},
      {"points_kept", "sparse points kept", "Input", "/points/kept", 0},
      {"points_dropped", "sparse points dropped", "Input", "/points/dropped", 0},
      {"background", "background", "Input", "/background/color", 0},
      {"loop_endpoint_l1", "loop-endpoint L1 (0-255)", "Completion", "/completion/loop_endpoint_l1", 2},
      {"anchor_error_mean", "anchor index error mean", "Completion", "/completion/anchor_index_error/mean", 2},
      {"anchor_error_max", "anchor index error max", "Completion", "/completion/anchor_index_error/max", 0},
      {"seconds_orbit", "orbit (s)", "Stage seconds", "/stages/orbit", 1},
      {"seconds_g0", "g0 (s)", "Stage seconds", "/stages/g0", 1},
      {"seconds_static_proxy", "static proxy (s)", "Stage seconds", "/stages/static_proxy", 1},
      {"seconds_completion", "completion (s)", "Stage seconds", "/stages/completion", 1},
      {"seconds_g1", "g1 (s)", "Stage seconds", "/stages/g1", 1},
      {"seconds_report", "report (s)", "Stage seconds", "/stages/report", 1},
      {"total_seconds", "total (s)", "Stage seconds", "/total_seconds", 1},
      {"seconds_g1_paper", "g1 paper-data (s, comparison)", "Stage seconds", "/comparison_seconds/g1_paper", 1},
      {"seconds_bound", "bound (s, comparison)", "Stage seconds", "/comparison_seconds/bound", 1},
      {"static_frame_varying_adjacent_l1", "frame-varying adj L1", "Static proxy",
       "/static_proxy/variants/frame_varying/adjacent_l1", 3, "/static_proxy/frame_varying/adjacent_l1"},
      {"static_frame_varying_adjacent_l1_p95", "frame-varying adj L1 P95", "Static proxy",
       "/static_proxy/variants/frame_varying/adjacent_l1_p95", 3, "/static_proxy/frame_varying/adjacent_l1_p95"},
      {"static_frame_varying_loop_l1", "frame-varying loop L1", "Static proxy",
       "/static_proxy/variants/frame_varying/loop_l1", 3, "/static_proxy/frame_varying/loop_l1"},
      {"static_fixed_slice_adjacent_l1", "fixed-slice adj L1", "Static proxy",
       "/static_proxy/variants/fixed_slice/adjacent_l1", 3, "/static_proxy/fixed_slice/adjacent_l1"},
      {"static_fixed_slice_adjacent_l1_p95", "fixed-slice adj L1 P95", "Static proxy",
       "/static_proxy/variants/fixed_slice/adjacent_l1_p95", 3, "/static_proxy/fixed_slice/adjacent_l1_p95"},
      {"static_fixed_slice_loop_l1", "fixed-slice loop L1", "Static proxy",
       "/static_proxy/variants/fixed_slice/loop_l1", 3, "/static_proxy/fixed_slice/loop_l1"},
      {"static_median_adjacent_l1", "median adj L1", "Static proxy",
       "/static_proxy/variants/median/adjacent_l1", 3, "/static_proxy/median/adjacent_l1"},
      {"static_median_adjacent_l1_p95", "median adj L1 P95", "Static proxy",
       "/static_proxy/variants/median/adjacent_l1_p95", 3, "/static_proxy/median/adjacent_l1_p95"},
      {"static_median_loop_l1", "median loop L1", "Static proxy",
       "/static_proxy/variants/median/loop_l1", 3, "/static_proxy/median/loop_l1"},
  };
  return c;
}

inline const std::vector<std::string>& sections() {
  static const std::vector<std::string> s = {"Coverage", "Orbit diagnostics", "Quality", "Fit to training frames",
                                             "Completion", "Input", "Stage seconds", "Static proxy"};
  return s;
}

inline std::string format_number(double d, int digits);

// The value at a JSON pointer, or null when any step is missing or of the wrong type.
inline nlohmann::json lookup(const nlohmann::json& j, const std::string& pointer) {
  if (!j.is_object()) return nullptr;
  try {
    const nlohmann::json::json_pointer p(pointer);
    if (!j.contains(p)) return nullptr;
    const nlohmann::json& v = j.at(p);
    if (v.is_number()) {
      const double d = v.get<double>();
      if (!std::isfinite(d)) return nullptr;
    }
    if (v.is_primitive()) return v;
    if (v.is_array() && !v.empty() && v.size() <= 4) {  // a small vector, e.g. a colour: "r,g,b"
      std::string joined;
      for (const auto& e : v) {
        if (!e.is_number()) return nullptr;
        if (!joined.empty()) joined += ",";
        joined += format_number(e.get<double>(), 3);
      }
      return joined;
    }
    return nullptr;  // objects and other arrays are not cells
  } catch (const nlohmann::json::exception&) {
    return nullptr;  // e.g. an array where an object was expected
  }
}

// Quality means over zero views are not measurements (mean_quality leaves 0).
inline bool quality_measured(const nlohmann::json& report, const std::string& pointer) {
  const std::size_t last = pointer.rfind('/');
  if (pointer.rfind("/quality/", 0) != 0 || last == std::string::npos) return true;
  const nlohmann::json views = lookup(report, pointer.substr(0, last) + "/views");
  return !(views.is_number() && views.get<double>() <= 0);
}

inline nlohmann::json cell(const nlohmann::json& report, const Column& c) {
  if (std::string(c.key) == "gain_gap_psnr") {
    const nlohmann::json r0 = cell(report, {"", "", "", "/quality/R0/gap_heldout/psnr", 0});
    const nlohmann::json r1 = cell(report, {"", "", "", "/quality/R1/gap_heldout/psnr", 0});
    if (r0.is_number() && r1.is_number()) return r1.get<double>() - r0.get<double>();
    return nullptr;
  }
  if (!quality_measured(report, c.pointer)) return nullptr;
  nlohmann::json v = lookup(report, c.pointer);
  if (v.is_null() && *c.alt) v = lookup(report, c.alt);
  return v;
}

inline std::string format_number(double d, int digits) {
  char b[64];
  std::snprintf(b, sizeof(b), "%.*f", digits, d);
  return b;
}

inline std::string markdown_cell(const nlohmann::json& v, int digits) {
  if (v.is_null()) return "-";
  if (v.is_boolean()) return v.get<bool>() ? "yes" : "no";
  if (v.is_number_integer()) return std::to_string(v.get<long long>());
  if (v.is_number()) return format_number(v.get<double>(), digits);
  std::string s = v.is_string() ? v.get<std::string>() : v.dump();
  std::string out;
  for (char ch : s) {
    if (ch == '|') out += "\\|";
    else if (ch == '\n' || ch == '\r') out += ' ';
    else out += ch;
  }
  return out;
}

inline std::string csv_field(const std::string& s) {
  if (s.find_first_of(",\"\n\r") == std::string::npos) return s;
  std::string q = "\"";
  for (char ch : s) {
    if (ch == '"') q += '"';
    q += ch;
  }
  return q + "\"";
}

inline std::string csv_cell(const nlohmann::json& v) {
  if (v.is_null()) return "";
  if (v.is_boolean()) return v.get<bool>() ? "true" : "false";
  if (v.is_number_integer()) return std::to_string(v.get<long long>());
  if (v.is_number()) {
    char b[64];
    std::snprintf(b, sizeof(b), "%.10g", v.get<double>());
    return b;
  }
  return csv_field(v.is_string() ? v.get<std::string>() : v.dump());
}

}  // namespace audit_detail

// Quantile q in [0, 1] of the values by linear interpolation between order
// statistics (see the top of this file). Requires at least one value.
inline double audit_quantile(std::vector<double> values, double q) {
  ensure(!values.empty(), "audit_quantile: no values");
  ensure(q >= 0 && q <= 1, "audit_quantile: q must lie in [0, 1], got ", q);
  std::sort(values.begin(), values.end());
  const double h = double(values.size() - 1) * q;
  const std::size_t lo = std::size_t(std::floor(h));
  const std::size_t hi = std::min(values.size() - 1, lo + 1);
  return values[lo] + (h - double(lo)) * (values[hi] - values[lo]);
}

// Reads <dir>/report.json (and orbit.json's "orbit" object, for the radius, when
// the file exists). A missing or unreadable report makes a failed row, not a throw.
inline AuditRow read_audit_row(const std::string& name, const std::string& dir) {
  namespace fs = std::filesystem;
  AuditRow row;
  row.name = name;
  const std::string report_path = (fs::path(dir) / "report.json").string();
  try {
    row.report = nlohmann::json::parse(read_file_bytes(report_path));
    ensure(row.report.is_object(), report_path, ": expected a JSON object");
  } catch (const nlohmann::json::exception& e) {
    row.report = nullptr;
    row.error = report_path + ": not valid JSON: " + e.what();
  } catch (const std::exception& e) {
    row.report = nullptr;
    row.error = e.what();
  }
  if (!row.error.empty()) return row;
  const std::string orbit_path = (fs::path(dir) / "orbit.json").string();
  std::error_code ec;
  if (!row.report.contains("orbit") && fs::exists(orbit_path, ec)) {
    try {
      const nlohmann::json o = nlohmann::json::parse(read_file_bytes(orbit_path));
      if (o.is_object() && o.contains("orbit") && o["orbit"].is_object()) row.report["orbit"] = o["orbit"];
    } catch (const std::exception&) {
      // The radius column shows "-"; the report itself is fine.
    }
  }
  return row;
}

// The table: {"columns": [{key, title, section, digits}], "rows": [{name, status,
// error, values: {key: value or null}}], "summary": [{name: "median" | "P90",
// values, counts}], "quantiles": how they are computed}.
inline nlohmann::json audit_table(const std::vector<AuditRow>& rows) {
  using namespace audit_detail;
  nlohmann::json table;
  nlohmann::json cols = nlohmann::json::array();
  for (const auto& c : columns())
    cols.push_back({{"key", c.key}, {"title", c.title}, {"section", c.section}, {"digits", c.digits}});
  table["columns"] = cols;
  std::map<std::string, std::vector<double>> samples;
  nlohmann::json out_rows = nlohmann::json::array();
  for (const auto& r : rows) {
    // Only successful inputs have cells and enter the summaries.
    const bool failed = !r.error.empty() || (!r.status.empty() && r.status != "ok");
    nlohmann::json values = nlohmann::json::object();
    for (const auto& c : columns()) {
      const nlohmann::json v = failed ? nlohmann::json() : cell(r.report, c);
      values[c.key] = v;
      // Booleans and strings have no median; numbers only.
      if (v.is_number()) samples[c.key].push_back(v.get<double>());
    }
    std::string status = r.status.empty() ? (failed ? "failed" : "ok") : r.status;
    out_rows.push_back({{"name", r.name}, {"status", status}, {"error", r.error}, {"values", values}});
  }
  table["rows"] = out_rows;
  nlohmann::json summary = nlohmann::json::array();
  for (const auto& [label, q] : std::vector<std::pair<std::string, double>>{{"median", 0.5}, {"P90", 0.9}}) {
    nlohmann::json values = nlohmann::json::object(), counts = nlohmann::json::object();
    for (const auto& c : columns()) {
      const auto it = samples.find(c.key);
      const bool have = it != samples.end() && !it->second.empty();
      values[c.key] = have ? nlohmann::json(audit_quantile(it->second, q)) : nlohmann::json();
      counts[c.key] = have ? it->second.size() : 0;
    }
    summary.push_back({{"name", label}, {"q", q}, {"values", values}, {"counts", counts}});
  }
  table["summary"] = summary;
  table["quantiles"] =
      "over the inputs that succeeded and have the value; linear interpolation between order statistics: "
      "h = (n-1) q, x[floor h] + (h - floor h)(x[floor h + 1] - x[floor h]); median q = 0.5, P90 q = 0.9";
  return table;
}

// Markdown: a status table (every input), then one table per section with a row
// per successful input and the median / P90 rows. The static-proxy section only
// appears when some input has it.
inline std::string audit_markdown(const nlohmann::json& table) {
  using audit_detail::markdown_cell;
  std::ostringstream md;
  const nlohmann::json& rows = table.at("rows");
  const nlohmann::json& cols = table.at("columns");
  md << "# OrbitForge audit\n\n";
  // Which part of a sharded run this is, so a task's table says which task wrote it.
  const nlohmann::json settings = table.value("audit", nlohmann::json::object());
  const std::string source = settings.value("shard_source", std::string("none"));
  if (source != "none")
    md << "Shard " << settings.value("shard", std::string("?")) << " from " << source << " ("
       << settings.value("shard_detail", std::string()) << ").\n\n";
  md << "## Inputs\n\n| input | status | error |\n|---|---|---|\n";
  std::size_t ok = 0;
  for (const auto& r : rows) {
    const bool good = r.value("status", std::string()) == "ok";
    ok += good ? 1 : 0;
    md << "| " << markdown_cell(r.at("name"), 0) << " | " << markdown_cell(r.at("status"), 0) << " | "
       << (r.value("error", std::string()).empty() ? std::string("-") : markdown_cell(r.at("error"), 0)) << " |\n";
  }
  md << "\n" << ok << " of " << rows.size() << " inputs succeeded. Median and P90 rows: "
     << table.value("quantiles", std::string()) << ".\n";
  for (const auto& section : audit_detail::sections()) {
    std::vector<const nlohmann::json*> sc;
    for (const auto& c : cols)
      if (c.at("section").get<std::string>() == section) sc.push_back(&c);
    if (sc.empty()) continue;
    bool any = false;
    for (const auto& r : rows)
      for (const auto* c : sc)
        if (r.at("status") == "ok" && !r.at("values").at(c->at("key").get<std::string>()).is_null()) any = true;
    if (section == "Static proxy" && !any) continue;
    md << "\n## " << section << "\n\n| input |";
    for (const auto* c : sc) md << " " << c->at("title").get<std::string>() << " |";
    md << "\n|---|";
    for (std::size_t k = 0; k < sc.size(); ++k) md << "---|";
    md << "\n";
    auto line = [&](const std::string& name, const nlohmann::json& values) {
      md << "| " << name << " |";
      for (const auto* c : sc) {
        const std::string key = c->at("key").get<std::string>();
        md << " " << markdown_cell(values.contains(key) ? values.at(key) : nlohmann::json(), c->at("digits").get<int>())
           << " |";
      }
      md << "\n";
    };
    for (const auto& r : rows)
      if (r.at("status") == "ok") line(markdown_cell(r.at("name"), 0), r.at("values"));
    for (const auto& s : table.at("summary")) line("**" + s.at("name").get<std::string>() + "**", s.at("values"));
  }
  return md.str();
}

// CSV (RFC 4180 quoting): name, status, error, then every column; one line per
// input, then the median and P90 lines (status "summary"). Missing values are empty.
inline std::string audit_csv(const nlohmann::json& table) {
  using audit_detail::csv_cell;
  std::ostringstream csv;
  const nlohmann::json& cols = table.at("columns");
  csv << "name,status,error";
  for (const auto& c : cols) csv << "," << c.at("key").get<std::string>();
  csv << "\n";
  auto line = [&](const nlohmann::json& name, const nlohmann::json& status, const nlohmann::json& error,
                  const nlohmann::json& values) {
    csv << csv_cell(name) << "," << csv_cell(status) << "," << csv_cell(error);
    for (const auto& c : cols) {
      const std::string key = c.at("key").get<std::string>();
      csv << "," << csv_cell(values.contains(key) ? values.at(key) : nlohmann::json());
    }
    csv << "\n";
  };
  for (const auto& r : table.at("rows")) line(r.at("name"), r.at("status"), r.at("error"), r.at("values"));
  for (const auto& s : table.at("summary")) line(s.at("name"), "summary", "", s.at("values"));
  return csv.str();
}

}  // namespace orbitforge
