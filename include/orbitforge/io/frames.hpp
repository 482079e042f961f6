#pragma once
// Frame ranges over a name-ordered camera list: "1-33" selects the first 33
// frames (1-based, inclusive), as the source video V0 is cut from a longer
// recording. Also accepted: "7" (one frame) and "7-" (frame 7 to the end).
#include <charconv>
#include <string>
#include <string_view>
#include <vector>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/core/error.hpp"
#include "orbitforge/io/text_reader.hpp"

namespace orbitforge {

struct FrameRange {
  int first = 1, last = -1;  // 1-based inclusive; last = -1 means to the end
};

inline FrameRange parse_frame_range(const std::string& text) {
  const std::string_view t = trim_view(text);
  auto number = [&](std::string_view s, const char* which) {
    int v = 0;
    const auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
    ensure(!s.empty() && ec == std::errc() && ptr == s.data() + s.size(), "frame range '", text, "': ", which,
           " frame '", s, "' is not a whole number (expected FIRST-LAST, FIRST- or FIRST, e.g. 1-33)");
    ensure(v >= 1, "frame range '", text, "': frames are numbered from 1, got ", v);
    return v;
  };
  FrameRange r;
  const std::size_t dash = t.find('-');
  if (dash == std::string_view::npos) {
    r.first = r.last = number(t, "first");
    return r;
  }
  r.first = number(trim_view(t.substr(0, dash)), "first");
  const std::string_view rest = trim_view(t.substr(dash + 1));
  if (!rest.empty()) {
    r.last = number(rest, "last");
    ensure(r.last >= r.first, "frame range '", text, "': last frame ", r.last, " is before first frame ", r.first);
  }
  return r;
}

template <class S>
std::vector<FrameCamera<S>> select_frames(const std::vector<FrameCamera<S>>& cams, FrameRange r) {
  const int n = static_cast<int>(cams.size());
  ensure(r.first >= 1, "frame range: first frame ", r.first, " is below 1");
  ensure(r.first <= n, "frame range ", r.first, "-", r.last, ": first frame ", r.first, " is beyond the ", n,
         " frames available");
  const int last = r.last < 0 ? n : r.last;
  ensure(last >= r.first, "frame range ", r.first, "-", r.last, ": last frame is before the first");
  ensure(last <= n, "frame range ", r.first, "-", r.last, ": last frame ", last, " is beyond the ", n,
         " frames available");
  return std::vector<FrameCamera<S>>(cams.begin() + (r.first - 1), cams.begin() + last);
}

// A range of video frame numbers over every frame of a video, registered or not
// (`frames[i].valid` false where the camera estimator did not register frame
// i + 1): the range's registered frames, and the others named. The same range
// means the same frames whichever frames the estimator kept.
template <class S>
struct RegisteredFrames {
  std::vector<FrameCamera<S>> cameras;  // registered frames of the range, in frame order
  std::vector<int> numbers;             // their 1-based frame numbers
  std::vector<std::string> skipped;     // "frame 29 (name)" for each unregistered frame of the range
};

template <class S>
RegisteredFrames<S> select_registered_frames(const std::vector<FrameCamera<S>>& frames, FrameRange r) {
  const int n = static_cast<int>(frames.size());
  const int last = r.last < 0 ? n : r.last;
  ensure(r.first <= n, "frame range ", r.first, "-", last, ": first frame ", r.first, " is beyond the ", n,
         " frames of the video");
  ensure(last <= n, "frame range ", r.first, "-", last, ": last frame ", last, " is beyond the ", n,
         " frames of the video");
  RegisteredFrames<S> out;
  for (int i = r.first - 1; i < last; ++i) {
    const auto& fc = frames[std::size_t(i)];
    if (fc.valid) {
      out.cameras.push_back(fc);
      out.numbers.push_back(i + 1);
    } else {
      out.skipped.push_back("frame " + std::to_string(i + 1) + " (" + fc.name + ")");
    }
  }
  ensure(!out.cameras.empty(), "frame range ", r.first, "-", last, ": none of its ", last - r.first + 1,
         " frames has a camera");
  return out;
}

}  // namespace orbitforge
