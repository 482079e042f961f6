#pragma once
// What the example programs share on the command line, over CLI11: one
// convention for exit codes (2 = bad arguments, 1 = bad input or failure,
// 0 = success, --help included), messages on stderr that name the flag, the value
// checks CLI11 does not have (thread counts, r,g,b colours, frame ranges), and the
// settings file a run writes and `--config FILE` replays.
#include <CLI/CLI.hpp>

#include <array>
#include <charconv>
#include <cmath>
#include <exception>
#include <functional>
#include <iostream>
#include <new>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/core/limits.hpp"
#include "orbitforge/io/frames.hpp"

namespace orbitforge::cli {

// Bad command-line arguments (exit status 2).
struct UsageError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// --help was answered on stdout (exit status 0).
struct HelpShown {};

// An App as every program sets it up: a flag given twice keeps its last value (as
// the hand-written parsers did, so scripts may override a flag they pass), option
// defaults appear in --help, and `--config FILE` reads a settings file.
inline void setup(CLI::App& app, bool with_config = false) {
  app.option_defaults()->multi_option_policy(CLI::MultiOptionPolicy::TakeLast)->always_capture_default();
  app.get_formatter()->column_width(34);
  if (with_config)
    app.set_config("--config", "",
                   "settings to start from (TOML, as a run writes to OUT/settings.toml); flags given override them")
        ->type_name("FILE");
}

// Parses argv into `app`: --help prints the usage on stdout and throws HelpShown;
// anything CLI11 refuses becomes a UsageError naming the program and the flag.
inline void parse(CLI::App& app, int argc, const char* const* argv) {
  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp&) {
    std::cout << app.help();
    throw HelpShown{};
  } catch (const CLI::CallForAllHelp&) {
    std::cout << app.help("", CLI::AppFormatMode::All);
    throw HelpShown{};
  } catch (const CLI::ParseError& e) {
    throw UsageError(app.get_name() + ": " + e.what() + "\n(" + app.get_name() + " --help lists every flag)");
  }
}

// Value checks, as CLI11 validators: each message names the flag (CLI11 prefixes it).

// A number that is finite (CLI11 reads "nan" and "inf" as numbers).
inline CLI::Validator finite() {
  return CLI::Validator(
      [](std::string& s) -> std::string {
        double x = 0;
        if (!CLI::detail::lexical_cast(s, x) || !std::isfinite(x)) return "expects a finite number, got '" + s + "'";
        return {};
      },
      "FINITE");
}

// A whole number in decimal: all of `s` (CLI11 alone would read "010" as octal 8).
inline bool decimal(const std::string& s, long long& x) {
  const char* end = s.data() + s.size();
  const auto [ptr, ec] = std::from_chars(s.data(), end, x);
  return !s.empty() && ec == std::errc() && ptr == end;
}

// A whole number at least `lo` (no upper bound but the type's), in decimal. A
// transform: it also writes the number back canonically, so "010" means 10.
inline CLI::Validator at_least(long long lo) {
  return CLI::Validator(
      [lo](std::string& s) -> std::string {
        long long x = 0;
        if (!decimal(s, x) || x < lo) return "expects an integer >= " + std::to_string(lo) + ", got '" + s + "'";
        s = std::to_string(x);
        return {};
      },
      ">=" + std::to_string(lo));
}

// A finite number for which `ok` holds; `need` says what it must be.
inline CLI::Validator number_where(bool (*ok)(double), const std::string& need, const std::string& name) {
  return CLI::Validator(
      [ok, need](std::string& s) -> std::string {
        double x = 0;
        if (!CLI::detail::lexical_cast(s, x) || !std::isfinite(x) || !ok(x)) return need + ", got '" + s + "'";
        return {};
      },
      name);
}

// A positive number (> 0).
inline CLI::Validator positive() {
  return number_where([](double x) { return x > 0; }, "must be a positive number", "POSITIVE");
}

// A finite number >= 0 (CLI::NonNegativeNumber's message prints the largest double).
inline CLI::Validator non_negative() {
  return number_where([](double x) { return x >= 0; }, "must be a finite number >= 0", "NON-NEGATIVE");
}

// --threads N: 0 (all hardware threads) up to orbitforge::Limits::max_threads,
// read when the flag is checked (the environment may raise the limit). A
// transform, as at_least.
inline CLI::Validator thread_count() {
  return CLI::Validator(
      [](std::string& s) -> std::string {
        long long n = 0;
        if (!decimal(s, n) || n < 0) return "expects a thread count >= 0 (0 = all), got '" + s + "'";
        const int max = limits().max_threads;
        if (n > max)
          return s + " is over the thread limit of " + std::to_string(max) +
                 " (orbitforge::Limits::max_threads; the environment variable ORBITFORGE_MAX_THREADS raises it)";
        s = std::to_string(n);
        return {};
      },
      "0..max_threads");
}

// "r,g,b" with each value in [0, 1]; throws Error naming what is wrong.
inline std::array<double, 3> parse_rgb(const std::string& text) {
  std::array<double, 3> c{};
  std::size_t pos = 0;
  for (int k = 0; k < 3; ++k) {
    const std::size_t comma = k < 2 ? text.find(',', pos) : std::string::npos;
    ensure(k == 2 || comma != std::string::npos, "expects r,g,b in [0,1], got '", text, "'");
    const std::string part = text.substr(pos, k < 2 ? comma - pos : std::string::npos);
    double x = 0;
    ensure(CLI::detail::lexical_cast(part, x) && std::isfinite(x), "expects r,g,b in [0,1], got '", text, "'");
    ensure(x >= 0 && x <= 1, "values must lie in [0,1], got '", text, "'");
    c[std::size_t(k)] = x;
    pos = comma + 1;
  }
  return c;
}

// r,g,b in [0, 1]; with `random_too` also the word "random".
inline CLI::Validator rgb(bool random_too = false) {
  return CLI::Validator(
      [random_too](std::string& s) -> std::string {
        if (random_too && s == "random") return {};
        try {
          parse_rgb(s);
        } catch (const Error& e) {
          return e.what();
        }
        return {};
      },
      random_too ? "r,g,b|random" : "r,g,b");
}

// A check by one of the library's parsers: its orbitforge::Error message (e.g.
// parse_frame_range's) becomes the flag's.
template <class Parse>
CLI::Validator checked_by(Parse parse, const std::string& name) {
  return CLI::Validator(
      [parse](std::string& s) -> std::string {
        try {
          parse(s);
        } catch (const Error& e) {
          return e.what();
        }
        return {};
      },
      name);
}

// A frame range A-B (1-based; "A-" runs to the last frame).
inline CLI::Validator frame_range() {
  return checked_by([](const std::string& s) { parse_frame_range(s); }, "A-B");
}

// A value that is left out of the settings file while it is zero (zero stands for
// "not given": the program or the protocol chooses).
template <class T>
CLI::Option* unset_when_zero(CLI::Option* o, const T& v) {
  o->default_function([&v] { return v == T(0) ? std::string() : CLI::detail::to_string(v); });
  o->capture_default_str();
  return o;
}

// Leaves an option out of the settings file: a run that did not use it (e.g.
// --frames of the synthetic input) does not record a value for it.
inline void leave_out(CLI::App& app, const std::string& name) {
  app.get_option(name)->configurable(false);
}

// Runs a validator on a parsed value again: CLI11 lets an empty argument ('')
// through without checking it.
inline void recheck(const std::string& program, const std::string& flag, std::string value, CLI::Validator v) {
  const std::string message = v(value);
  if (!message.empty()) throw UsageError(program + ": " + flag + ": " + message);
}

// An option whose unset state (std::nullopt) means "the program decides"; the
// settings file leaves it out while unset.
template <class T>
CLI::Option* add_optional(CLI::App& app, const std::string& name, std::optional<T>& v, const std::string& help) {
  CLI::Option* o = app.add_option_function<T>(name, [&v](const T& x) { v = x; }, help);
  o->default_function([&v] { return v ? CLI::detail::to_string(*v) : std::string(); });
  return o;
}

// A flag that sets `target` to `value` when given; the settings file records
// whether the run's `target` ended at `value` (so a replay gives the same value).
template <class T>
CLI::Option* add_setting_flag(CLI::App& app, const std::string& name, T& target, T value, const std::string& help) {
  CLI::Option* o = app.add_flag_callback(name, [&target, value] { target = value; }, help);
  o->default_function([&target, value] { return target == value ? std::string("true") : std::string("false"); });
  return o;
}

// A flag that asks for what is now the default, kept so that old commands still
// parse: it sets `target` to `value`, and the settings file records it as not
// given (the setting flag that turns the default off records the run's value).
// Define it before that flag, so that the setting flag given with it wins.
template <class T>
CLI::Option* add_old_default_flag(CLI::App& app, const std::string& name, T& target, T value) {
  CLI::Option* o =
      app.add_flag_callback(name, [&target, value] { target = value; }, "(the default; kept for old commands)");
  o->default_function([] { return std::string("false"); });
  return o;
}

// The command line as a shell would take it back: each argument quoted where needed.
inline std::string shell_command(int argc, const char* const* argv) {
  std::string cmd;
  for (int i = 0; i < argc; ++i) {
    const std::string a = argv[i];
    if (i) cmd += ' ';
    const bool plain = !a.empty() && a.find_first_not_of("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ"
                                                         "0123456789-_./=:,+@%") == std::string::npos;
    if (plain) {
      cmd += a;
      continue;
    }
    cmd += '\'';
    for (char c : a) cmd += c == '\'' ? std::string("'\\''") : std::string(1, c);
    cmd += '\'';
  }
  return cmd;
}

// The settings file of a parsed App (CLI11's config format, TOML): every
// configurable option with the value the run used (given, from --config, or the
// default the program resolved), each under its description, so that
// `--config FILE` replays the run. Options still unset (an empty value, e.g. no
// --background) are left out and stay unset on replay.
inline std::string settings_text(CLI::App& app) {
  for (CLI::Option* o : app.get_options()) {
    if (!o->get_configurable() || o->count() > 0) continue;
    o->capture_default_str();
    if (o->get_default_str().empty() && o->get_expected_min() > 0) o->run_callback_for_default(false);
  }
  return app.config_to_str(true, true);
}

// The message of an exception that reaches a program's top level. The library
// turns the allocations it can describe into orbitforge::OutOfMemory ("out of
// memory while rendering a 30000x30000 frame ... (about 28.5 GiB requested)"); a
// bare std::bad_alloc from anywhere else still says what it means.
inline std::string describe(const std::exception& e) {
  if (dynamic_cast<const std::bad_alloc*>(&e))
    return std::string("out of memory (") + e.what() + " from an allocation the library does not describe)";
  return e.what();
}

// Runs a program body with the exit-code convention above.
inline int run(const std::function<int()>& body) {
  try {
    return body();
  } catch (const HelpShown&) {
    return 0;
  } catch (const UsageError& e) {
    std::cerr << e.what() << "\n";
    return 2;
  } catch (const std::exception& e) {
    std::cerr << describe(e) << "\n";
    return 1;
  }
}

}  // namespace orbitforge::cli
