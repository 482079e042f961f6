#pragma once
// Stage records: what lets an interrupted pipeline resume without trusting file
// names. Once every output of a stage is written (each atomically),
// stages/<stage>.json records
//
//   {"key": K, "seconds": s, "settings": {...},
//    "outputs": [{"path": "gmed0.ply", "size": bytes, "fnv1a": "hex"}, ...]}
//
// where K hashes the stage's inputs and settings. A stage is current only when
// its record parses, its key matches, and every output it lists exists with the
// recorded size and content hash; otherwise the stage runs again and the reason
// is reported. The record is written last, so a crash leaves either no record or
// a record whose outputs are all complete.
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>
#include <system_error>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/core/hash.hpp"
#include "orbitforge/io/atomic_file.hpp"

namespace orbitforge {

struct StageCheck {
  bool current = false;
  std::string why;  // when not current: the first reason found
};

namespace stage_record_detail {
namespace fs = std::filesystem;

inline fs::path record_path(const std::string& out, const std::string& stage) {
  return fs::path(out) / "stages" / (stage + ".json");
}

// A relative path that stays in the run folder: not empty, not absolute, no ".."
// component (a name like "clip..v2.png" is fine) and no NUL (which would cut the
// name short when the file is opened).
inline bool inside_run_folder(const std::string& p) {
  if (p.empty() || p.front() == '/' || p.find('\0') != std::string::npos) return false;
  for (const auto& part : fs::path(p))
    if (part == "..") return false;
  return true;
}

inline nlohmann::json describe_output(const std::string& out, const std::string& relative) {
  const std::string bytes = read_file_bytes((fs::path(out) / relative).string());
  return {{"path", relative}, {"size", bytes.size()}, {"fnv1a", hex64(fnv1a(bytes))}};
}
}  // namespace stage_record_detail

// Parses a record's text; throws Error naming `where` when it is not a record.
inline nlohmann::json parse_stage_record(const std::string& text, const std::string& where) {
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(text);
  } catch (const nlohmann::json::exception& e) {
    fail(where, ": not valid JSON (", e.what(), ")");
  }
  ensure(j.is_object() && j.contains("key") && j["key"].is_string(), where, ": no \"key\" string");
  ensure(j.contains("outputs") && j["outputs"].is_array(), where, ": no \"outputs\" list");
  for (const auto& o : j["outputs"]) {
    ensure(o.is_object() && o.contains("path") && o["path"].is_string() && o.contains("size") &&
               o["size"].is_number_unsigned() && o.contains("fnv1a") && o["fnv1a"].is_string(),
           where, ": an output entry lacks path, size or fnv1a");
    const std::string p = o["path"].get<std::string>();
    ensure(stage_record_detail::inside_run_folder(p), where, ": output path '", p, "' is not inside the run folder");
  }
  if (j.contains("seconds")) ensure(j["seconds"].is_number(), where, ": \"seconds\" is not a number");
  return j;
}

// Whether `stage` may be skipped: its record matches `key` and lists exactly
// `outputs` (or, when `outputs` is empty, whatever non-empty list it recorded),
// each unchanged since it was recorded.
inline StageCheck check_stage(const std::string& out, const std::string& stage, const std::string& key,
                              const std::vector<std::string>& outputs) {
  using namespace stage_record_detail;
  StageCheck c;
  const fs::path rp = record_path(out, stage);
  std::error_code ec;
  if (!fs::exists(rp, ec)) {
    c.why = "no record";
    return c;
  }
  nlohmann::json j;
  try {
    j = parse_stage_record(read_file_bytes(rp.string()), rp.string());
  } catch (const Error& e) {
    c.why = std::string("record unreadable: ") + e.what();
    return c;
  }
  if (j["key"].get<std::string>() != key) {
    c.why = "inputs or settings changed";
    return c;
  }
  std::vector<std::string> listed;
  for (const auto& o : j["outputs"]) listed.push_back(o["path"].get<std::string>());
  if (outputs.empty() ? listed.empty() : listed != outputs) {
    c.why = "the record lists other outputs";
    return c;
  }
  for (const auto& o : j["outputs"]) {
    const std::string rel = o["path"].get<std::string>();
    const fs::path p = fs::path(out) / rel;
    if (!fs::is_regular_file(p, ec)) {
      c.why = rel + " is missing";
      return c;
    }
    const auto size = fs::file_size(p, ec);
    if (ec || size != o["size"].get<std::uint64_t>()) {
      c.why = rel + " changed size since it was recorded (" + std::to_string(ec ? 0 : size) + " bytes, recorded " +
              std::to_string(o["size"].get<std::uint64_t>()) + ")";
      return c;
    }
    if (hex64(fnv1a(read_file_bytes(p.string()))) != o["fnv1a"].get<std::string>()) {
      c.why = rel + " changed content since it was recorded (hash mismatch)";
      return c;
    }
  }
  c.current = true;
  return c;
}

// Writes the record (after the outputs): key, wall seconds (when finite), settings
// and the size and hash of every output. Error when a name or setting is not UTF-8.
inline void record_stage(const std::string& out, const std::string& stage, const std::string& key, double seconds,
                         const nlohmann::json& settings, const std::vector<std::string>& outputs) {
  using namespace stage_record_detail;
  fs::create_directories(fs::path(out) / "stages");
  nlohmann::json list = nlohmann::json::array();
  for (const auto& o : outputs) {
    ensure(inside_run_folder(o), record_path(out, stage).string(), ": output path '", o,
           "' is not inside the run folder");
    list.push_back(describe_output(out, o));
  }
  nlohmann::json j = {{"key", key}, {"settings", settings}, {"outputs", list}};
  if (std::isfinite(seconds)) j["seconds"] = seconds;  // JSON has no NaN or infinity (dumped as null)
  std::string text;
  try {
    text = j.dump(1) + "\n";
  } catch (const nlohmann::json::type_error& e) {  // a string that is not UTF-8: JSON cannot hold it
    fail(record_path(out, stage).string(), ": cannot record an output name or setting that is not UTF-8 text (",
         e.what(), ")");
  }
  write_file_atomic(record_path(out, stage).string(), text);
}

inline double recorded_seconds(const std::string& out, const std::string& stage) {
  using namespace stage_record_detail;
  const std::string p = record_path(out, stage).string();
  const auto j = parse_stage_record(read_file_bytes(p), p);
  return j.value("seconds", 0.0);
}

// Whether `stage`'s record lists `relative` among its outputs (so the file is the
// one that stage wrote, not a leftover of an earlier run with other settings).
inline bool recorded_output(const std::string& out, const std::string& stage, const std::string& relative) {
  using namespace stage_record_detail;
  const std::string p = record_path(out, stage).string();
  std::error_code ec;
  if (!fs::exists(p, ec)) return false;
  const nlohmann::json record = parse_stage_record(read_file_bytes(p), p);
  for (const auto& o : record["outputs"])
    if (o["path"] == relative) return true;
  return false;
}

}  // namespace orbitforge
