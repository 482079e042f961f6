#pragma once
// The embedded synthetic scene (pipeline/inputs/synthetic_input.hpp) as the
// pipeline's recorded input.
#include <algorithm>
#include <sstream>
#include <string>

#include "orbitforge/pipeline/inputs/recorded_input.hpp"
#include "orbitforge/pipeline/inputs/synthetic_input.hpp"
#include "orbitforge/splat/renderer.hpp"

namespace orbitforge {

// The embedded synthetic recorded input: frames rendered from the ground-truth
// scene at the TRUE cameras; the recorded (noisy) cameras are what the pipeline
// sees. The first p.source_frames frames are the source.
template <class Scalar>
PipelineInput<Scalar> synthetic_pipeline_input(const SyntheticInputParams& p, int threads = 0) {
  const SyntheticInput<Scalar> syn = make_synthetic_input<Scalar>(p);
  PipelineInput<Scalar> in;
  in.width = p.width;
  in.height = p.height;
  in.cameras = syn.recorded;
  RenderParams<Scalar> rp;
  rp.threads = threads;
  Renderer<Scalar> r(rp);
  for (const auto& cam : syn.true_cameras) in.images.push_back(r.render(SceneView<Scalar>(syn.scene), cam).color);
  for (auto& img : in.images)
    for (auto& v : img.data) v = std::min(Scalar(1), std::max(Scalar(0), v));
  select_source(in, "1-" + std::to_string(p.source_frames));
  std::ostringstream os;
  os << "synthetic (" << p.frames << " frames, source 1-" << p.source_frames << ", " << p.width << "x" << p.height
     << ", seed " << p.seed << (p.backdrop ? ", textured backdrop" : "") << ")";
  in.description = os.str();
  in.camera_path = "synthetic: noisy recorded cameras of every frame";
  return in;
}

}  // namespace orbitforge
