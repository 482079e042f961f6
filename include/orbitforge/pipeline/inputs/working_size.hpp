#pragma once
// The size a recorded input's frames are worked at: an exact size, the frames'
// own, or a number of pixels on the longer side with the frames' aspect kept
// (a 640x480 photograph is worked at 512x384, not squeezed into 512x512).
#include <algorithm>
#include <array>
#include <cmath>
#include <string>

#include "orbitforge/core/error.hpp"

namespace orbitforge {

struct WorkingSize {
  int width = 0, height = 0;  // exact size; both 0 with long_side 0: the frames' own
  int long_side = 0;          // > 0: this many pixels on the longer side, aspect kept

  static WorkingSize exact(int w, int h) { return {w, h, 0}; }
  static WorkingSize native() { return {}; }
  static WorkingSize longer_side(int pixels) { return {0, 0, pixels}; }
  // The loaders' (width, height) convention: 0 x 0 is the frames' own size.
  static WorkingSize from_pair(int w, int h) { return w == 0 && h == 0 ? native() : exact(w, h); }

  bool is_native() const { return width == 0 && height == 0 && long_side == 0; }

  // For settings and reports: "512x384", "the frames' own" or "512 on the longer side".
  std::string describe() const {
    if (long_side > 0) return std::to_string(long_side) + " on the longer side";
    if (is_native()) return "the frames' own";
    return std::to_string(width) + "x" + std::to_string(height);
  }

  // The size for frames of frame_w x frame_h.
  std::array<int, 2> for_frames(int frame_w, int frame_h) const {
    ensure(frame_w > 0 && frame_h > 0, "working size: frames of ", frame_w, "x", frame_h);
    if (long_side > 0) {
      const double aspect = double(frame_w) / double(frame_h);
      return aspect >= 1 ? std::array<int, 2>{long_side, std::max(8, int(std::lround(long_side / aspect)))}
                         : std::array<int, 2>{std::max(8, int(std::lround(long_side * aspect))), long_side};
    }
    if (is_native()) return {frame_w, frame_h};
    return {width, height};
  }

  void check(const char* who) const {
    if (long_side > 0)
      ensure(long_side >= 8, who, ": working size of ", long_side, " pixels on the longer side is too small");
    else
      ensure(is_native() || (width >= 8 && height >= 8), who, ": working size ", width, "x", height,
             " is too small");
  }
};

}  // namespace orbitforge
