#pragma once
// Endpoint-window layout of the completion request (paper, "Endpoint-Window
// Completion Layout"), sparse anchors, the map back to canonical order, and the
// assembly plan of the completed orbit.
//
// With S_arc = [0, k], P = N - 1 (the period; view N - 1 duplicates view 0) and
// s = floor(k / 2), synthetic frame j shows canonical view (s + j) mod P:
//   j = 0 .. k - s          known tail  (views s .. k)
//   j = k - s + 1 .. P - s - 1   the gap (views k + 1 .. P - 1), to be completed
//   j = P - s .. P          known head  (views 0 .. s); frame P shows view s again,
// so the clip ends on the view it started from and the model fills an interval
// whose two ends are known. Completion models want 8m + 1 frames: N = 361 already
// is; otherwise the clip is padded to the next 8m + 1 by repeating its last view
// (known frames at the end, so the closure is kept).
//
// Anchors: source frames 1, 1 + stride, 1 + 2 stride, ... (1-based, in order of
// the successful source cameras) plus the last one, each placed at the synthetic
// index of its own canonical bin ("source-angle aligned"; anchor index error 0).
// The naive option "target_half" ignores azimuths and spreads the anchors
// uniformly, in source order, over the canonical half orbit [0, P/2] (as if the
// source always covered half of the orbit), then maps those views to synthetic
// indices. Anchor index error = |placed synthetic index - synthetic index of the
// anchor's own canonical bin|.
#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/geometry/binning.hpp"

namespace orbitforge {

enum class AnchorPlacement { source_aligned, target_half };

inline const char* anchor_placement_name(AnchorPlacement p) {
  return p == AnchorPlacement::source_aligned ? "source_aligned" : "target_half";
}

struct LayoutParams {
  int anchor_stride = 24;
  AnchorPlacement placement = AnchorPlacement::source_aligned;
};

struct LayoutAnchor {
  int source_index = 0;       // 0-based among the successful source cameras
  std::string name;
  int canonical = 0;          // the anchor's own canonical bin
  int synthetic = 0;          // where the layout places it
  int aligned_synthetic = 0;  // synthetic index of its canonical bin
};

// Smallest 8m + 1 >= views.
inline int completion_frame_count(int views) {
  ensure(views >= 1, "completion_frame_count: views = ", views);
  return ((views - 1 + 7) / 8) * 8 + 1;
}

struct CompletionLayout {
  int views = 0;   // N
  int frames = 0;  // 8m + 1 >= N
  int start = 0;   // s
  int arc_end = 0; // k
  std::vector<int> synthetic_to_canonical;  // [frames]
  std::vector<char> known;                  // [frames]: 1 where the view is in S_arc
  std::vector<LayoutAnchor> anchors;
  double anchor_error_mean = 0, anchor_error_max = 0;

  int period() const { return views - 1; }
  // The synthetic index (in [0, P)) that shows canonical view v (v = N - 1 maps like 0).
  int canonical_to_synthetic(int v) const {
    ensure(v >= 0 && v < views, "CompletionLayout::canonical_to_synthetic: view ", v, " outside [0, ", views, ")");
    const int P = period();
    return ((v % P) - start % P + P) % P;
  }
};

// `support`: from bin_sources; `names`: the successful source cameras' names in
// source order (same length as support.source_bins).
inline CompletionLayout endpoint_window_layout(const SupportBins& support, const std::vector<std::string>& names,
                                               const LayoutParams& params = {}) {
  ensure(support.views >= 3, "endpoint_window_layout: need at least 3 canonical views, got ", support.views);
  ensure(names.size() == support.source_bins.size(), "endpoint_window_layout: ", names.size(), " names for ",
         support.source_bins.size(), " source cameras");
  ensure(params.anchor_stride >= 1, "endpoint_window_layout: anchor stride must be >= 1, got ", params.anchor_stride);
  CompletionLayout L;
  L.views = support.views;
  L.frames = completion_frame_count(support.views);
  L.arc_end = support.arc_end;
  const int P = L.period();
  L.start = support.arc_end / 2;
  L.synthetic_to_canonical.resize(L.frames);
  L.known.resize(L.frames);
  for (int j = 0; j < L.frames; ++j) {
    const int v = (L.start + std::min(j, P)) % P;
    L.synthetic_to_canonical[j] = v;
    L.known[j] = support.in_arc(v) ? 1 : 0;
  }
  // Anchor source indices: 0, stride, 2 stride, ... and the last.
  const int T = int(support.source_bins.size());
  std::vector<int> picks;
  for (int t = 0; t < T; t += params.anchor_stride) picks.push_back(t);
  if (T > 0 && picks.back() != T - 1) picks.push_back(T - 1);
  const int n = int(picks.size());
  double err_sum = 0;
  for (int a = 0; a < n; ++a) {
    LayoutAnchor A;
    A.source_index = picks[a];
    A.name = names[picks[a]];
    A.canonical = support.source_bins[picks[a]];
    A.aligned_synthetic = L.canonical_to_synthetic(A.canonical);
    if (params.placement == AnchorPlacement::source_aligned) {
      A.synthetic = A.aligned_synthetic;
    } else {
      const int placed_view = n > 1 ? int(std::lround(double(a) * double(P / 2) / double(n - 1))) : 0;
      A.synthetic = L.canonical_to_synthetic(placed_view);
    }
    const double e = std::abs(A.synthetic - A.aligned_synthetic);
    err_sum += e;
    L.anchor_error_max = std::max(L.anchor_error_max, e);
    L.anchors.push_back(A);
  }
  L.anchor_error_mean = n > 0 ? err_sum / n : 0.0;
  return L;
}

// Where each canonical view of the completed orbit comes from.
struct AssemblyEntry {
  enum class From { first_reconstruction, completion };
  From from = From::first_reconstruction;
  int canonical = 0;
  int synthetic = -1;  // the completion frame used (only for From::completion)
};

// Views in S_arc come from the first reconstruction's render R0, views in U_gap
// from the completed clip at the synthetic index that shows them.
inline std::vector<AssemblyEntry> assembly_plan(const CompletionLayout& L) {
  std::vector<AssemblyEntry> plan(L.views);
  for (int v = 0; v < L.views; ++v) {
    plan[v].canonical = v;
    if (v <= L.arc_end) {
      plan[v].from = AssemblyEntry::From::first_reconstruction;
    } else {
      plan[v].from = AssemblyEntry::From::completion;
      plan[v].synthetic = L.canonical_to_synthetic(v);
    }
  }
  return plan;
}

}  // namespace orbitforge
