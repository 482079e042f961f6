// Deformable training on a scene like real photographs: a small world (a camera
// estimator's arbitrary unit), a cluttered backdrop behind the object, a few
// frames spread over a wide arc. Deformable training must not end clearly below
// static training on the same frames: additive scale offsets in world units once
// shrank every small Gaussian to a point here, and the count either collapsed
// (every Gaussian pruned) or exploded (clones of clones) while the fit got worse.
#include <catch2/catch.hpp>

#include <cmath>

#include "orbitforge/metrics/image.hpp"
#include "orbitforge/pipeline/inputs/recorded_input.hpp"
#include "orbitforge/pipeline/inputs/synthetic_pipeline_input.hpp"
#include "orbitforge/train/init.hpp"
#include "orbitforge/train/trainer.hpp"

using namespace orbitforge;

namespace {

#ifdef ORBITFORGE_TEST_QUICK
constexpr int kIterations = 600;
#else
constexpr int kIterations = 1500;
#endif

struct Outcome {
  double train_psnr = 0, heldout_psnr = 0;
  std::size_t gaussians = 0, peak = 0;
};

Outcome train(const std::vector<TrainFrame<float>>& frames, const std::vector<TrainFrame<float>>& heldout,
              bool deformable) {
  InitParams ip;
  ip.random_points = 20000;
  TrainParams p;
  p.iterations = kIterations;
  p.threads = 2;
  p.deformable = deformable;
  p.min_densify_interval = 50;  // as reconstruct and the pipeline
  p.field.depth = 3;
  p.field.width = 32;
  Trainer<float> t(frames, init_random(frame_cameras(frames), ip), p);
  Outcome o;
  while (t.iteration() < p.iterations) o.peak = std::max(o.peak, t.step().gaussians);
  o.gaussians = t.scene().size();
  for (const auto& f : frames) o.train_psnr += psnr(clamp01(t.render(f.camera, f.time)), f.image) / frames.size();
  for (const auto& f : heldout) o.heldout_psnr += psnr(clamp01(t.render(f.camera, f.time)), f.image) / heldout.size();
  return o;
}

}  // namespace

TEST_CASE("deformable training keeps up with static training on a small, cluttered scene", "[train][deformable]") {
  SyntheticInputParams sp;
  sp.frames = 16;
  sp.source_frames = 9;
  sp.arc_deg = 360.0 * 15.0 / 16.0;  // 9 frames over ~190 degrees, as a ring of photographs
  sp.width = 64;
  sp.height = 48;
  sp.focal = 60;
  sp.backdrop = true;
  sp.world_scale = 0.15;  // cameras ~0.6 units from the object, as Middlebury's ring
  sp.position_noise = 0;
  sp.rotation_noise_deg = 0;
  sp.drift_per_frame = 0;
  sp.object_gaussians = 1500;
  sp.ground_gaussians = 800;
  sp.backdrop_gaussians = 2500;
  const PipelineInput<float> in = synthetic_pipeline_input<float>(sp, 2);
  std::vector<TrainFrame<float>> frames, heldout;
  for (int f : in.source) {
    TrainFrame<float> t;
    t.image = in.images[std::size_t(f)];
    t.camera = in.cameras[std::size_t(f)].camera;
    t.time = float(in.time_code(f));
    t.name = in.cameras[std::size_t(f)].name;
    (f % 3 == 1 ? heldout : frames).push_back(std::move(t));  // frames 2, 5, 8 held out
  }
  REQUIRE(frames.size() == 6);
  const Outcome st = train(frames, heldout, false);
  const Outcome de = train(frames, heldout, true);
  INFO("static: " << st.gaussians << " Gaussians (peak " << st.peak << "), train " << st.train_psnr << " dB, held out "
                  << st.heldout_psnr << " dB");
  INFO("deformable: " << de.gaussians << " Gaussians (peak " << de.peak << "), train " << de.train_psnr
                      << " dB, held out " << de.heldout_psnr << " dB");
  CHECK(st.train_psnr > 20);
  // At about 45 dB the deformable model's training PSNR moves by 1.4 dB with the
  // order its field's gradients are summed in: 43.7 on one thread and 45.1 on
  // two with Eigen's products, 44.1 on two with the dense kernels (the static
  // model is the same on any thread count). Held out, the three agree within 0.04 dB.
  CHECK(de.train_psnr > st.train_psnr - 2.0);
  CHECK(de.heldout_psnr > st.heldout_psnr - 1.0);
  CHECK(de.gaussians > st.gaussians / 3);  // no collapse
  CHECK(de.peak < 3 * st.peak);            // no explosion
}
