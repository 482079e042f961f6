#pragma once
// Line and token helpers shared by the text parsers. Every failure names
// "file:line" so that a bad input can be found and fixed by hand.
// Numbers are parsed with std::from_chars: locale-independent and strict (the
// whole token must be a number; "1.5abc" is an error, not 1.5).
#include <charconv>
#include <cstdint>
#include <limits>
#include <ostream>
#include <string>
#include <string_view>
#include <system_error>
#include <type_traits>
#include <vector>

#include "orbitforge/core/error.hpp"

namespace orbitforge {

inline bool is_space_char(char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\n' || c == '\v' || c == '\f'; }

inline std::string_view trim_view(std::string_view s) {
  while (!s.empty() && is_space_char(s.front())) s.remove_prefix(1);
  while (!s.empty() && is_space_char(s.back())) s.remove_suffix(1);
  return s;
}

// Whitespace-separated tokens of one line (views into `line`).
inline std::vector<std::string_view> split_tokens(std::string_view line) {
  std::vector<std::string_view> tokens;
  std::size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && is_space_char(line[i])) ++i;
    const std::size_t start = i;
    while (i < line.size() && !is_space_char(line[i])) ++i;
    if (i > start) tokens.push_back(line.substr(start, i - start));
  }
  return tokens;
}

// Where a token came from, for messages: "file:line".
struct TextLocation {
  const std::string* file = nullptr;
  std::size_t line = 0;
};

inline std::ostream& operator<<(std::ostream& os, const TextLocation& at) {
  return os << (at.file ? *at.file : std::string("<text>")) << ':' << at.line;
}

// A double; accepts "nan"/"inf" (the caller decides what non-finite values mean).
inline double parse_double_token(std::string_view token, const TextLocation& at, const char* what) {
  std::string_view t = token;
  if (!t.empty() && t.front() == '+') t.remove_prefix(1);
  double value = 0;
  const auto [ptr, ec] = std::from_chars(t.data(), t.data() + t.size(), value);
  if (ec == std::errc::result_out_of_range) {
    fail(at, ": ", what, " '", token, "' is out of the range of a double");
  }
  ensure(ec == std::errc() && ptr == t.data() + t.size() && !t.empty(), at, ": ", what, " '", token,
         "' is not a number");
  return value;
}

template <class Int>
Int parse_int_token(std::string_view token, const TextLocation& at, const char* what) {
  static_assert(std::is_integral<Int>::value, "integer type expected");
  std::string_view t = token;
  if (!t.empty() && t.front() == '+') t.remove_prefix(1);
  Int value = 0;
  const auto [ptr, ec] = std::from_chars(t.data(), t.data() + t.size(), value);
  if (ec == std::errc::result_out_of_range) {
    fail(at, ": ", what, " '", token, "' is out of range (", std::numeric_limits<Int>::min(), " .. ",
         std::numeric_limits<Int>::max(), ")");
  }
  ensure(ec == std::errc() && ptr == t.data() + t.size() && !t.empty(), at, ": ", what, " '", token,
         "' is not an integer");
  return value;
}

// Walks the lines of an in-memory text ('\n' or "\r\n" endings).
class LineReader {
 public:
  LineReader(std::string_view text, const std::string& file_name) : text_(text), file_(&file_name) {}

  // Next raw line (without its end-of-line characters); false at end of text.
  bool next_line(std::string_view& line) {
    if (pos_ >= text_.size()) return false;
    const std::size_t end = text_.find('\n', pos_);
    const std::size_t stop = end == std::string_view::npos ? text_.size() : end;
    line = text_.substr(pos_, stop - pos_);
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    pos_ = end == std::string_view::npos ? text_.size() : end + 1;
    ++line_number_;
    return true;
  }
  // Next line that is neither blank nor a '#' comment.
  bool next_data_line(std::string_view& line) {
    std::string_view l;
    while (next_line(l)) {
      const std::string_view t = trim_view(l);
      if (t.empty() || t.front() == '#') continue;
      line = l;
      return true;
    }
    return false;
  }
  TextLocation location() const { return {file_, line_number_}; }
  const std::string& file_name() const { return *file_; }

 private:
  std::string_view text_;
  const std::string* file_;
  std::size_t pos_ = 0;
  std::size_t line_number_ = 0;
};

}  // namespace orbitforge
