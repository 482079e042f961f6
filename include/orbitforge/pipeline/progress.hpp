#pragma once
// Progress of the pipeline's long steps (training, rendering), as events a
// caller turns into whatever display it has. The library itself only offers a
// plain line logger; a terminal progress bar belongs to the program (see
// examples/support/progress_bar.hpp).
#include <cstdio>
#include <functional>
#include <memory>
#include <string>

namespace orbitforge {

struct ProgressEvent {
  std::string label;   // "G0", "R0", "G1", ...
  int done = 0, total = 0;
  std::string detail;  // e.g. "psnr 31.20  40213 gaussians"
};

using ProgressSink = std::function<void(const ProgressEvent&)>;

// A line on stderr each time a step passes another tenth of its total.
inline ProgressSink progress_lines_to_stderr() {
  struct State {
    std::string label;
    int decile = -1;
  };
  auto st = std::make_shared<State>();
  return [st](const ProgressEvent& e) {
    const int total = e.total > 0 ? e.total : 1;
    const int decile = int(10.0 * e.done / total);
    if (e.label != st->label) {
      st->label = e.label;
      st->decile = -1;
    }
    if (decile != st->decile || e.done >= total) {
      std::fprintf(stderr, "%s: %d/%d %s\n", e.label.c_str(), e.done, total, e.detail.c_str());
      st->decile = decile;
    }
  };
}

}  // namespace orbitforge
