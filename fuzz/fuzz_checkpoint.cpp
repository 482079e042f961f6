// libFuzzer target: training checkpoints (Trainer::load_checkpoint, with the
// checksum trailer of nn/binary_io.hpp).
//
// Input: byte 0 = flags, the rest = bytes.
//   flag 1: the checksum is recomputed: bytes are a checkpoint body and get a valid
//           trailer appended (append_checksum), so that mutations get past the
//           checksum to the structural checks (the important mode);
//           otherwise bytes are a whole checkpoint file, trailer included.
//   flag 2: load into a deformable trainer (otherwise a static one).
//   flag 4: after an accepted load, train one step (when the budget allows).
// The payload (checked_payload) goes to load_checkpoint(std::istream&) of a fresh
// Trainer<float> on two tiny frames (8x8) and a 3-Gaussian scene, built per input
// from frames made once per process. An accepted checkpoint must leave a trainer
// whose scene is finite and sized consistently: consistent arrays, SH degree within
// the maximum, iteration within the budget, a finite positive extent, optimizer
// groups of the scene's rows and the parameters' widths with valid Adam settings,
// densification statistics of the scene's size and (deformable) a finite network
// unless the still-scene check baked it in.
// orbitforge::Error is expected for bad input; anything else is a bug (abort).
//
// Seeds: run with an empty or missing corpus folder and checkpoints of the same
// trainers (untrained and after 2 steps, static and deformable, both modes) are
// put there first (see LLVMFuzzerInitialize).
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "orbitforge/nn/binary_io.hpp"
#include "orbitforge/pipeline/inputs/synthetic_input.hpp"
#include "orbitforge/splat/renderer.hpp"
#include "orbitforge/train/init.hpp"
#include "orbitforge/train/trainer.hpp"

#include "seed_dirs.hpp"

namespace fs = std::filesystem;
using namespace orbitforge;
using S = float;

namespace {

[[noreturn]] void bug(const std::string& what) {
  std::fprintf(stderr, "fuzz_checkpoint: invariant broken: %s\n", what.c_str());
  std::abort();
}

struct Setup {
  std::vector<TrainFrame<S>> frames;
  GaussianScene<S> initial;
  TrainParams params_static, params_deformable;
};

const Setup& setup() {
  static const Setup s = [] {
    Setup st;
    SyntheticInputParams p;
    p.frames = p.source_frames = 3;
    p.width = p.height = 8;
    p.focal = 10;
    p.object_gaussians = 20;
    p.ground_gaussians = 10;
    const auto in = make_synthetic_input<S>(p);
    RenderParams<S> rp;
    rp.threads = 1;
    rp.background = {S(1), S(1), S(1)};
    Renderer<S> r(rp);
    std::vector<Camera<S>> cams;
    for (int i = 0; i < 2; ++i) {
      TrainFrame<S> f;
      f.camera = in.true_cameras[std::size_t(i)];
      f.image = r.render(SceneView<S>(in.scene), f.camera).color;
      f.time = S(i);
      f.name = "f" + std::to_string(i);
      cams.push_back(f.camera);
      st.frames.push_back(std::move(f));
    }
    InitParams ip;
    ip.random_points = 3;
    ip.seed = 3;
    st.initial = init_random(cams, camera_extent(cams), ip);
    TrainParams tp;
    tp.iterations = 4;
    tp.threads = 1;
    tp.seed = 11;
    tp.background = {1, 1, 1};
    tp.max_sh_degree = 1;
    tp.densify_schedule.densify_interval = 1000;
    st.params_static = tp;
    tp.deformable = true;
    tp.field.depth = 2;
    tp.field.width = 8;
    tp.field.x_frequencies = 1;
    tp.field.t_frequencies = 1;
    st.params_deformable = tp;
    return st;
  }();
  return s;
}

std::unique_ptr<Trainer<S>> make_trainer(bool deformable) {
  const Setup& s = setup();
  return std::make_unique<Trainer<S>>(s.frames, s.initial, deformable ? s.params_deformable : s.params_static);
}

template <class V>
void all_finite(const V& v, const char* what) {
  for (const auto x : v)
    if (!std::isfinite(double(x))) bug(std::string("accepted a non-finite value in ") + what);
}

void check_trainer(const Trainer<S>& t, bool deformable) {
  const TrainParams& p = t.params();
  const GaussianScene<S>& s = t.scene();
  try {
    s.check_consistent();
  } catch (const Error& e) {
    bug(std::string("accepted an inconsistent scene: ") + e.what());
  }
  const std::size_t n = s.size();
  if (s.opacity_logits.size() != n) bug("opacity count differs from the scene size");
  if (s.sh_degree < 0 || s.sh_degree > p.max_sh_degree) bug("SH degree outside 0..max_sh_degree");
  all_finite(s.means, "means");
  all_finite(s.rotations, "rotations");
  all_finite(s.log_scales, "log_scales");
  all_finite(s.opacity_logits, "opacity_logits");
  all_finite(s.sh, "sh");
  if (t.iteration() < 0 || t.iteration() > p.iterations) bug("iteration outside the budget");
  if (!std::isfinite(double(t.extent())) || !(t.extent() > 0)) bug("accepted a non-finite or non-positive extent");
  const Adam<S>& adam = t.optimizer();
  const AdamParams& ap = adam.params();
  if (!(ap.beta1 >= 0 && ap.beta1 < 1 && ap.beta2 >= 0 && ap.beta2 < 1 && ap.eps >= 0 && std::isfinite(ap.eps)))
    bug("accepted Adam settings its constructor refuses");
  if (adam.group_count() != 6) bug("optimizer group count");
  const int rest = std::max(1, 3 * (sh_coefficient_count(p.max_sh_degree) - 1));
  const int widths[6] = {3, 4, 3, 1, 3, rest};
  for (int g = 0; g < 6; ++g) {
    const auto& gr = adam.group(g);
    if (gr.rows != n) bug("optimizer group rows differ from the scene size");
    if (gr.row_width != widths[g])
      bug("optimizer group '" + gr.name + "' has row width " + std::to_string(gr.row_width) + ", its parameter " +
          std::to_string(widths[g]));
    if (gr.m.size() != gr.size() || gr.v.size() != gr.size()) bug("optimizer moments sized wrongly");
    if (gr.step < 0) bug("negative optimizer step count");
  }
  const auto& st = t.densify_stats();
  if (st.grad_sum.size() != n || st.count.size() != n || st.max_radius.size() != n) bug("densify stats size");
  if (deformable && !t.field() && !t.field_baked()) bug("deformable trainer without a field that was not baked in");
  if (!deformable && (t.field() || t.field_baked())) bug("static trainer with a deformation field");
  if (t.field()) all_finite(t.field()->parameters(), "deformation parameters");
}

void load_and_check(const std::string& payload, bool deformable, bool step) {
  auto t = make_trainer(deformable);
  try {
    std::istringstream is(payload, std::ios::binary);
    t->load_checkpoint(is);
  } catch (const Error&) {
    return;
  }
  check_trainer(*t, deformable);
  if (step && t->iteration() < t->params().iterations) {
    try {
      t->step();
    } catch (const Error&) {
    }
  }
}

std::string checkpoint_body(bool deformable, int iterations) {
  auto t = make_trainer(deformable);
  t->train(iterations);
  std::ostringstream os(std::ios::binary);
  t->save_checkpoint(os);
  return os.str();
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 1) return 0;
  const unsigned flags = data[0];
  const bool recompute = flags & 1, deformable = flags & 2, step = flags & 4;
  std::string bytes(reinterpret_cast<const char*>(data + 1), size - 1);
  if (recompute) binary_io::append_checksum(bytes);
  std::string payload;
  try {
    payload = binary_io::checked_payload(bytes);
  } catch (const Error&) {
    if (recompute) bug("a freshly appended checksum was refused");
    return 0;
  }
  if (recompute && payload.size() != size - 1) bug("checked_payload returned another body");
  load_and_check(payload, deformable, step);
  return 0;
}

// Seeds: a corpus folder named on the command line that is missing or empty
// gets checkpoints of the trainers this target loads into.
extern "C" int LLVMFuzzerInitialize(int* argc, char*** argv) {
  const std::vector<std::string> dirs = empty_corpus_dirs(*argc, *argv);
  if (dirs.empty()) return 0;
  int k = 0;
  for (bool deformable : {false, true})
    for (int iterations : {0, 2}) {
      const std::string body = checkpoint_body(deformable, iterations);
      std::string file = body;
      binary_io::append_checksum(file);
      const unsigned base = (deformable ? 2u : 0u) | 4u;
      const std::string inputs[2] = {std::string(1, char(base | 1u)) + body, std::string(1, char(base)) + file};
      for (const auto& in : inputs) {
        for (const auto& d : dirs) {
          fs::create_directories(d);
          std::ofstream f(fs::path(d) / ("seed-" + std::to_string(k)), std::ios::binary);
          f.write(in.data(), std::streamsize(in.size()));
        }
        ++k;
      }
    }
  return 0;
}
