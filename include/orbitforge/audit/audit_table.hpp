#pragma once
// The audit over many inputs: one table of every input's
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
#include <map>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "orbitforge/audit/audit_columns.hpp"
#include "orbitforge/core/error.hpp"
#include "orbitforge/io/atomic_file.hpp"

namespace orbitforge {

// One input: its name, its report.json (with orbit.json's "orbit" object merged in
// under "orbit" when available) and, when it failed, why (non-empty).
struct AuditRow {
  std::string name;
  nlohmann::json report;
  std::string error;
  std::string status;  // empty: "ok" or "failed" from `error`; anything but "ok" (e.g. "stopped") counts as failed
};

namespace audit_detail {

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
    // Opt-in figures (static-proxy diagnostics, view-fitted scores) only when some run has them.
    if ((section == "Static proxy" || section == "Quality, views fitted") && !any) continue;
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
