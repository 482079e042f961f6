#pragma once
// Which inputs of a many-input audit this process takes: a shard i of n, from
// --shard i/n or from the scheduler that started the process (a Slurm array
// task, a Kubernetes Indexed Job), and the inputs that shard owns.
#include <algorithm>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "orbitforge/core/error.hpp"

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

}  // namespace orbitforge
