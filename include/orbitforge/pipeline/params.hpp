#pragma once
// Settings of the whole method (run_pipeline, pipeline.hpp) and the exception
// that pauses it while an external completion is pending.
#include <array>
#include <functional>
#include <sstream>
#include <string>
#include <type_traits>
#include <utility>

#include "orbitforge/core/error.hpp"
#include "orbitforge/geometry/completion_layout.hpp"
#include "orbitforge/geometry/orbit.hpp"
#include "orbitforge/pipeline/completion/perturbed.hpp"
#include "orbitforge/pipeline/inputs/recalibration.hpp"
#include "orbitforge/pipeline/progress.hpp"
#include "orbitforge/train/trainer.hpp"

namespace orbitforge {

// What the second reconstruction G1 trains on.
enum class G1Data {
  // V_hat as published: R0's renders on the supported arc at the canonical
  // cameras, and the completion frames on the gap.
  paper,
  // The source frames G0 trained on, at their estimated cameras, and the
  // completion frames on the gap (R0's renders only with g1_arc_renders).
  source,
};

inline const char* g1_data_name(G1Data d) { return d == G1Data::paper ? "paper" : "source"; }

inline G1Data parse_g1_data(const std::string& s) {
  if (s == "paper") return G1Data::paper;
  if (s == "source") return G1Data::source;
  fail("G1 data '", s, "': expected paper or source");
}

// How a run was asked for, kept for the record: run_pipeline copies it into
// report.json ("invocation") and nothing else reads it. It enters no stage key, so
// a resumed run spelled differently still skips its verified stages, and a
// skipped report keeps the invocation of the run that wrote it.
struct RunInvocation {
  std::string command;   // the command line, e.g. shell-quoted
  std::string settings;  // the settings the caller resolved, e.g. the text of a settings file it wrote
  std::string memory_pages;  // which pages the process's heap got (core/huge_pages.hpp's huge_page_state)
  bool empty() const { return command.empty() && settings.empty(); }
};

// The training settings the method starts from: TrainParams's own, with the
// still-scene check on (TrainParams::still_check_iterations, still_check.hpp).
// A video of a still object then trains G0 static once its deformation field
// is shown to gain nothing over its bake; a moving one keeps the field. On the
// recorded videos at the default budget the check baked two of five (G0
// 0.54-0.60x, the whole method 0.72-0.77x, R1 within 0.21 dB) and kept the
// others at no measurable cost (docs/benchmarks.md). And coarse-to-fine by the
// budget (kCoarseLevelsByBudget: one level from 10,000 iterations, none below).
// --protocol paper turns both off.
inline TrainParams method_train_defaults() {
  TrainParams t;
  t.still_check_iterations = 500;
  t.coarse_levels = kCoarseLevelsByBudget;
  return t;
}

struct PipelineParams {
  OrbitParams orbit;                // views, elevation offset, ... (its width/height: see canonical_width)
  int canonical_width = 0, canonical_height = 0;  // canonical render grid; 0 = the input's working size
  LayoutParams layout;
  std::string completion = "oracle";  // external | oracle | perturbed | none
  PerturbParams perturb;            // strengths of the "perturbed" provider
  bool request_conditioning = true; // external request: R0's known frames as conditioning (else sparse anchors only)
  std::string negative_prompt;      // written into the external request's manifest
  std::string prompt;               // original text; the video prompt is make_prompt(prompt)
  // Per reconstruction, chosen by measurement for 512x512 inputs (docs/audit.md).
  int iters_g0 = 3000, iters_g1 = 3000;
  bool deformable = true;
  int median_samples = 128;         // MedianGS T_m
  bool g1_from_gmed0 = true;        // initialise G1 from Gmed0 (else like G0: points / random)
  // G1 (and the bound) static or deformable. Deformable G1 is the paper's: its
  // time code is the orbit position, so each Gaussian is seen during only part
  // of [0, 1], and the MedianGS bake takes medians over mostly unconstrained
  // times (docs/audit.md measures what that costs).
  bool g1_deformable = false;
  // The plateau stop (train.plateau_window) on G1 too, and on the comparisons
  // trained as G1 is (the bound, G1 on V_hat); false: on G0 only, and G1 trains
  // its whole budget (docs/benchmarks.md, "The plateau stop on G0 alone").
  bool plateau_g1 = true;
  G1Data g1_data = G1Data::source;  // G1's training set (see G1Data)
  bool g1_arc_renders = false;      // with G1Data::source: add R0's arc renders too
  // The lens G1 gives the completion frames (and the report their gap views):
  // true, the source cameras' (a video model continues its source's lens, and
  // the external provider's frames are requested at it); false, the one the
  // provider gave with each frame. The oracle on the user's path gives the
  // reference model's focal length, a few per cent off the source cameras':
  // G1 then trains on two lenses (docs/cameras.md measures what that costs).
  bool g1_source_lens = true;
  // G1's cameras on the user's path: COLMAP again on the source frames and the
  // completion together (stages/recalibrate.hpp).
  RecalibrateParams recalibrate;
  // G1 turns and zooms each completion frame's camera to fit its image
  // (metrics/view_alignment.hpp, G1's scene of that moment held fixed) once,
  // after this fraction of its iterations; 0: never. A completion frame lands
  // a degree or two from the camera it was requested at (and the oracle's
  // frames come from another estimate), which G1 would otherwise learn as
  // blur at the seams.
  double g1_refine_completion_at = 0;
  int g1_source_repeats = 1;        // sampling weights (TrainFrame::repeats) of source frames ...
  int g1_completion_repeats = 1;    // ... and of completion frames
  // Comparisons for audits (each one more reconstruction; not part of the method):
  bool compare_g1_paper = false;    // also train G1 on the paper's V_hat (stage g1_paper)
  bool oracle_bound = false;        // train the oracle bound (stage bound; recorded inputs only)
  int render_stride = 1;            // R0 / R1 at every K-th canonical view
  bool static_proxy_diagnostics = false;  // opt-in: G0 rendered frame-varying / fixed slice / MedianGS on the orbit
  // Opt-in scoring: the withheld and gap views scored again after each view's
  // camera is turned and zoomed about its centre to fit its image
  // (metrics/view_alignment.hpp), which separates the scene's error from the
  // scoring cameras' own.
  bool score_view_fitted = false;
  std::size_t init_points = 20000;  // random initial cloud when the input has no points
  int checkpoint_every = 500;       // partial training checkpoints (0 = none)
  // The published densification schedule scaled to a short budget densifies every
  // few iterations (interval 100 * iters / 30000), on statistics of a handful of
  // views, and the Gaussian count explodes (5000 -> 170000 in 200 of 1000
  // iterations at 96x96). Short budgets keep at least this interval.
  int min_densify_interval = 50;
  int threads = 0;
  unsigned seed = 0;
  double min_source_arc_deg = 20;   // refuse sources that cover less
  bool progress = true;             // report progress (through on_progress, or lines on stderr)
  ProgressSink on_progress;         // where progress goes when `progress` (default: lines on stderr)
  // Called after every training iteration (label "G0" / "G1"); may throw to stop
  // a run, which then resumes from the last partial checkpoint.
  std::function<void(const std::string& label, int iteration)> on_iteration;
  // The other training settings. Seven of its fields have owners above (or in the
  // input): iterations (iters_g0 / iters_g1), deformable (deformable /
  // g1_deformable), seed, threads, min_densify_interval, and background and
  // random_background (the input's). Here they stay at TrainParams's defaults or repeat the owner's
  // value; anything else is refused by check_train_owners, naming both fields.
  TrainParams train = method_train_defaults();
  RunInvocation invocation;  // for report.json only (see RunInvocation)
};

// Refuses a value in params.train that its owner (see PipelineParams::train)
// would contradict, naming both fields; `background` is the input's.
inline void check_train_owners(const PipelineParams& p, const std::array<double, 3>& background,
                               bool random_background = false) {
  const TrainParams unset;
  auto refuse_if = [](bool conflict, const char* field, const auto& value, const std::string& owner,
                      const auto& owner_value, const auto& default_value) {
    if (!conflict) return;
    auto str = [](const auto& v) {
      std::ostringstream os;
      if constexpr (std::is_same_v<std::decay_t<decltype(v)>, std::array<double, 3>>)
        os << "{" << v[0] << ", " << v[1] << ", " << v[2] << "}";
      else
        os << std::boolalpha << v;
      return os.str();
    };
    fail("pipeline: params.train.", field, " = ", str(value), " conflicts with ", owner, " = ", str(owner_value),
         ", which sets it; set ", owner, ", and leave params.train.", field, " at its default (", str(default_value),
         ") or equal to it");
  };
  const TrainParams& t = p.train;
  for (const auto& [owner, iters] :
       {std::pair<const char*, int>{"params.iters_g0", p.iters_g0}, {"params.iters_g1", p.iters_g1}})
    refuse_if(t.iterations != unset.iterations && t.iterations != iters, "iterations", t.iterations, owner, iters,
              unset.iterations);
  // G1 paper is always deformable; G0, G1 and the bound as their fields say.
  for (const auto& [owner, deformable] :
       {std::pair<const char*, bool>{"params.deformable", p.deformable}, {"params.g1_deformable", p.g1_deformable}})
    refuse_if(t.deformable != unset.deformable && t.deformable != deformable, "deformable", t.deformable, owner,
              deformable, unset.deformable);
  refuse_if(t.seed != unset.seed && t.seed != p.seed, "seed", t.seed, "params.seed", p.seed, unset.seed);
  refuse_if(t.threads != unset.threads && t.threads != p.threads, "threads", t.threads, "params.threads", p.threads,
            unset.threads);
  refuse_if(t.min_densify_interval != unset.min_densify_interval && t.min_densify_interval != p.min_densify_interval,
            "min_densify_interval", t.min_densify_interval, "params.min_densify_interval", p.min_densify_interval,
            unset.min_densify_interval);
  refuse_if(t.background != unset.background && t.background != background, "background", t.background,
            "the input's background (PipelineInput::background)", background, unset.background);
  refuse_if(t.random_background != unset.random_background && t.random_background != random_background,
            "random_background", t.random_background, "PipelineInput::random_background", random_background,
            unset.random_background);
  // A learned colour would have to follow G0 into R0, the completion and G1.
  ensure(!t.learned_background, "pipeline: params.train.learned_background is not supported: every stage renders "
                                "with the input's background (reconstruct --background learned learns one)");
}

// The external provider is waiting for completed frames.
class PipelineStopped : public Error {
 public:
  explicit PipelineStopped(const std::string& what) : Error(what) {}
};

}  // namespace orbitforge
