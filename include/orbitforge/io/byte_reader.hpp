#pragma once
// Bounds-checked little-endian reads from an in-memory file. Every read checks
// the remaining size first, and counts read from the file are checked against
// the bytes left before anything is allocated, so a corrupt count cannot make
// a parser allocate gigabytes. Messages name the file and the byte offset.
#include <cstdint>
#include <cstring>
#include <string>
#include <string_view>
#include <type_traits>

#include "orbitforge/core/error.hpp"

namespace orbitforge {

class ByteReader {
 public:
  ByteReader(std::string_view bytes, const std::string& file_name) : bytes_(bytes), file_(&file_name) {}

  std::size_t offset() const { return pos_; }
  std::size_t remaining() const { return bytes_.size() - pos_; }
  bool at_end() const { return pos_ == bytes_.size(); }
  const std::string& file_name() const { return *file_; }

  // Fixed-size little-endian value (integers and IEEE floats).
  template <class T>
  T read(const char* what) {
    static_assert(std::is_arithmetic<T>::value, "arithmetic type expected");
    require(sizeof(T), what);
    std::uint64_t raw = 0;
    for (std::size_t i = 0; i < sizeof(T); ++i) {
      raw |= std::uint64_t(static_cast<unsigned char>(bytes_[pos_ + i])) << (8 * i);
    }
    pos_ += sizeof(T);
    T value;
    if constexpr (sizeof(T) == 1) {
      const auto b = static_cast<std::uint8_t>(raw);
      std::memcpy(&value, &b, 1);
    } else if constexpr (sizeof(T) == 2) {
      const auto b = static_cast<std::uint16_t>(raw);
      std::memcpy(&value, &b, 2);
    } else if constexpr (sizeof(T) == 4) {
      const auto b = static_cast<std::uint32_t>(raw);
      std::memcpy(&value, &b, 4);
    } else {
      static_assert(sizeof(T) == 8, "1, 2, 4 or 8 byte types");
      std::memcpy(&value, &raw, 8);
    }
    return value;
  }

  // A NUL-terminated string (the NUL is consumed, not returned).
  std::string read_cstring(const char* what) {
    const std::size_t start = pos_;
    const std::size_t end = bytes_.find('\0', pos_);
    ensure(end != std::string_view::npos, *file_, ": byte offset ", start, ": ", what,
           " has no terminating NUL before the end of the file");
    pos_ = end + 1;
    return std::string(bytes_.substr(start, end - start));
  }

  void skip(std::size_t n, const char* what) {
    require(n, what);
    pos_ += n;
  }

  std::string_view take(std::size_t n, const char* what) {
    require(n, what);
    const std::string_view v = bytes_.substr(pos_, n);
    pos_ += n;
    return v;
  }

  // A count read from the file, each item needing at least `min_item_bytes`:
  // fails when the rest of the file cannot possibly hold that many.
  void check_count(std::uint64_t count, std::size_t min_item_bytes, const char* what) const {
    const std::uint64_t fits = min_item_bytes == 0 ? UINT64_MAX : remaining() / min_item_bytes;
    ensure(count <= fits, *file_, ": byte offset ", pos_, ": ", what, " count ", count,
           " cannot fit in the ", remaining(), " bytes left (each needs at least ", min_item_bytes,
           " bytes): truncated or corrupt file");
  }

 private:
  void require(std::size_t n, const char* what) const {
    ensure(n <= remaining(), *file_, ": byte offset ", pos_, ": truncated file: ", what, " needs ", n,
           " bytes, only ", remaining(), " left");
  }

  std::string_view bytes_;
  const std::string* file_;
  std::size_t pos_ = 0;
};

}  // namespace orbitforge
