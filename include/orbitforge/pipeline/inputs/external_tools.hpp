#pragma once
// Running external programs (ffmpeg, colmap) from the pipeline layer: finding a
// program on PATH, the message when it is missing (naming the Debian package),
// and running one command with its output kept in a log file.
//
// Commands are argument vectors started with posix_spawn: no shell, so paths
// with spaces or quotes reach the program unchanged. stdin is /dev/null (a tool
// that asks a question gets end of file instead of hanging), stdout and stderr
// both go to the log, which starts with the command line (shell-quoted, so it
// can be pasted into a terminal). A failure names the tool, its exit status (or
// signal) and the log file, with the log's last lines.
//
// POSIX only. Only the pipeline and example layers call external programs; the
// core, io, geometry, splat and train headers never do.
#include <fcntl.h>
#include <spawn.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "orbitforge/core/error.hpp"

extern char** environ;

namespace orbitforge {

// One external command: `tool` names it in messages ("colmap mapper"), argv[0]
// is the program (a name looked up on PATH, or a path containing '/'), `env`
// adds or replaces environment variables for it.
struct ToolCommand {
  std::string tool;
  std::vector<std::string> argv;
  std::vector<std::pair<std::string, std::string>> env;
};

struct ToolRun {
  std::string program;  // the executable that ran (resolved path)
  double seconds = 0;
};

// The executable `name` resolves to in the ':'-separated `path_list` (empty
// entries mean the current folder, as in a shell), or "" when none. A name
// containing '/' is taken as a path.
inline std::string find_program(const std::string& name, const std::string& path_list) {
  namespace fs = std::filesystem;
  auto executable = [](const fs::path& p) {
    std::error_code ec;
    return fs::is_regular_file(p, ec) && ::access(p.c_str(), X_OK) == 0;
  };
  if (name.empty()) return "";
  if (name.find('/') != std::string::npos) return executable(name) ? name : "";
  std::size_t pos = 0;
  for (;;) {
    const std::size_t colon = path_list.find(':', pos);
    const std::string dir = path_list.substr(pos, colon == std::string::npos ? std::string::npos : colon - pos);
    const fs::path candidate = fs::path(dir.empty() ? "." : dir) / name;
    if (executable(candidate)) return candidate.string();
    if (colon == std::string::npos) return "";
    pos = colon + 1;
  }
}

inline std::string find_program(const std::string& name) {
  const char* path = std::getenv("PATH");
  // No PATH at all: the default search list of execvp.
  return find_program(name, path ? std::string(path) : std::string("/usr/local/bin:/usr/bin:/bin"));
}

// "full_pipeline: --video needs the ffmpeg program (Debian package ffmpeg): not found on PATH"
inline std::string missing_program_message(const std::string& who, const std::string& needed_by,
                                           const std::string& program, const std::string& debian_package) {
  return who + ": " + needed_by + " needs the " + program + " program (Debian package " + debian_package +
         "): not found on PATH";
}

// Throws Error with missing_program_message when `program` is not on PATH.
inline void require_program(const std::string& who, const std::string& needed_by, const std::string& program,
                            const std::string& debian_package) {
  if (find_program(program).empty()) throw Error(missing_program_message(who, needed_by, program, debian_package));
}

// A word as a POSIX shell reads it back unchanged (for logs and messages only;
// commands never go through a shell).
inline std::string shell_quote(const std::string& s) {
  if (!s.empty() && s.find_first_not_of("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_-+=.,/:%@") ==
                        std::string::npos)
    return s;
  std::string q = "'";
  for (char c : s) q += c == '\'' ? std::string("'\\''") : std::string(1, c);
  return q + "'";
}

inline std::string command_text(const ToolCommand& c) {
  std::string t;
  for (const auto& [k, v] : c.env) t += k + "=" + shell_quote(v) + " ";
  for (std::size_t i = 0; i < c.argv.size(); ++i) t += (i ? " " : "") + shell_quote(c.argv[i]);
  return t;
}

namespace external_tools_detail {

// The last `n` non-empty lines of a text file, each indented (for error messages).
inline std::string last_lines(const std::string& path, std::size_t n) {
  std::ifstream in(path, std::ios::binary);
  std::vector<std::string> lines;
  std::string line;
  while (std::getline(in, line)) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.find_first_not_of(" \t") == std::string::npos) continue;
    lines.push_back(line);
    if (lines.size() > n) lines.erase(lines.begin());
  }
  std::string s;
  for (const auto& l : lines) s += "\n    " + l;
  return s;
}

// environ with `env` added or replacing same-named variables.
inline std::vector<std::string> environment(const std::vector<std::pair<std::string, std::string>>& env) {
  std::vector<std::string> out;
  for (char** e = environ; e && *e; ++e) {
    const std::string kv(*e);
    bool replaced = false;
    for (const auto& [k, v] : env)
      if (kv.compare(0, k.size() + 1, k + "=") == 0) replaced = true;
    if (!replaced) out.push_back(kv);
  }
  for (const auto& [k, v] : env) out.push_back(k + "=" + v);
  return out;
}

inline std::vector<char*> c_strings(std::vector<std::string>& v) {
  std::vector<char*> p;
  for (auto& s : v) p.push_back(s.data());
  p.push_back(nullptr);
  return p;
}

}  // namespace external_tools_detail

// Runs `c` to completion with stdout and stderr appended to `log_path` (created
// fresh, starting with the command line). Throws Error when the program is not
// found, cannot start, is killed or exits with a non-zero status.
inline ToolRun run_tool(const ToolCommand& c, const std::string& log_path) {
  using namespace external_tools_detail;
  ensure(!c.argv.empty(), c.tool, ": empty command");
  ToolRun r;
  r.program = find_program(c.argv[0]);
  ensure(!r.program.empty(), c.tool, ": the program ", c.argv[0], " is not found on PATH");
  {
    std::error_code ec;
    const auto parent = std::filesystem::path(log_path).parent_path();
    if (!parent.empty()) std::filesystem::create_directories(parent, ec);
    std::ofstream log(log_path, std::ios::binary | std::ios::trunc);
    ensure(log.is_open(), c.tool, ": cannot write its log ", log_path);
    log << "$ " << command_text(c) << "\n";
    ensure(bool(log), c.tool, ": cannot write its log ", log_path);
  }

  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, 0, "/dev/null", O_RDONLY, 0);
  posix_spawn_file_actions_addopen(&actions, 1, log_path.c_str(), O_WRONLY | O_APPEND, 0);
  posix_spawn_file_actions_adddup2(&actions, 1, 2);
  std::vector<std::string> args = c.argv, envs = environment(c.env);
  std::vector<char*> argv = c_strings(args), envp = c_strings(envs);

  const auto t0 = std::chrono::steady_clock::now();
  pid_t pid = 0;
  const int spawn_error = posix_spawn(&pid, r.program.c_str(), &actions, nullptr, argv.data(), envp.data());
  posix_spawn_file_actions_destroy(&actions);
  ensure(spawn_error == 0, c.tool, ": cannot start ", r.program, ": ", std::strerror(spawn_error), " (log ", log_path,
         ")");
  int status = 0;
  while (::waitpid(pid, &status, 0) < 0) {
    if (errno == EINTR) continue;
    fail(c.tool, ": waiting for ", r.program, " failed: ", std::strerror(errno));
  }
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (WIFEXITED(status) && WEXITSTATUS(status) == 0) return r;
  std::ostringstream why;
  if (WIFEXITED(status)) {
    // posix_spawn reports exec failures in the child as exit status 127.
    why << "failed with exit status " << WEXITSTATUS(status);
  } else if (WIFSIGNALED(status)) {
    why << "was killed by signal " << WTERMSIG(status) << " (" << ::strsignal(WTERMSIG(status)) << ")";
  } else {
    why << "ended abnormally (wait status " << status << ")";
  }
  fail(c.tool, " ", why.str(), "; its log: ", log_path, "; last lines:", last_lines(log_path, 6));
}

}  // namespace orbitforge
