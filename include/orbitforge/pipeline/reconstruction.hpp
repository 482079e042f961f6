#pragma once
// The pipeline's reconstructions (G0, G1 and the oracle bound): training that
// resumes, the MedianGS bake, the initial scene, and renders along the orbit.
//
// Resuming: a training run saves dir/partial.bin every checkpoint_every
// iterations and dir/checkpoint.bin when it ends, each with a .key file naming
// the stage key it belongs to. The checkpoint files end in a checksum
// (Trainer::save_checkpoint): a damaged one is reported and training starts from
// the beginning (or from the other checkpoint) instead.
// A run whose finished checkpoint matches its key does not train again: an
// interrupt after training costs only the work after it (bake, renders).
#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "orbitforge/core/hash.hpp"
#include "orbitforge/core/parallel_for.hpp"
#include "orbitforge/deform/median_baker.hpp"
#include "orbitforge/io/atomic_file.hpp"
#include "orbitforge/io/image_io.hpp"
#include "orbitforge/pipeline/run_state.hpp"
#include "orbitforge/pipeline/training_record.hpp"
#include "orbitforge/splat/renderer.hpp"
#include "orbitforge/train/init.hpp"
#include "orbitforge/train/trainer.hpp"

namespace orbitforge {

// A stage's training set as a file (<stage>/frames.json): each frame's name and
// the hash of the pixels it trained on, so a check can tell that no held-out
// image reached training by its content, not only by its name.
template <class Scalar>
void write_frame_list(const std::string& path, const std::vector<TrainFrame<Scalar>>& frames) {
  nlohmann::json list = nlohmann::json::array();
  for (const auto& f : frames)
    list.push_back({{"name", f.name},
                    {"image_hash", hex64(fnv1a(f.image.data.data(), f.image.data.size() * sizeof(Scalar)))}});
  write_file_atomic(path, nlohmann::json({{"frames", list}}).dump(1) + "\n");
}

namespace reconstruction_detail {
namespace fs = std::filesystem;

// Loads `file` into the trainer when `file`.key holds `key`; false (with a
// message) when the file is absent, belongs to other settings, or is damaged.
template <class Scalar>
bool try_resume(Trainer<Scalar>& trainer, const std::string& file, const std::string& key, const std::string& label,
                const std::function<void(const std::string&)>& log) {
  std::error_code ec;
  const std::string key_file = file + ".key";
  if (!fs::exists(file, ec) || !fs::exists(key_file, ec)) return false;
  if (read_file_bytes(key_file) != key) return false;
  try {
    trainer.load_checkpoint(file);
    return true;
  } catch (const Error& e) {
    log(label + ": " + fs::path(file).filename().string() + " not usable (" + e.what() + "); not resuming from it");
    return false;
  }
}
// The "timing" of a training.json written when the training ran, or null: a
// run that reuses a finished checkpoint keeps the record of the sitting that trained it.
inline nlohmann::json recorded_timing(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) return nullptr;
  try {
    const nlohmann::json j = nlohmann::json::parse(read_file_bytes(path));
    if (j.is_object() && j.contains("timing") && j["timing"].is_object()) return j["timing"];
  } catch (const std::exception&) {
  }
  return nullptr;
}
}  // namespace reconstruction_detail

// Trains `frames` from `init` (resuming when it can), saves dir/checkpoint.bin
// and dir/training.json (training_record.hpp), and returns the MedianGS bake
// (the trained scene itself for static training, or when training ended within
// the deformation warm-up). `after_step` runs after every iteration and once
// after resuming; it may move the cameras of `frames` (the trainer holds them
// by reference) if it tells the trainer (Trainer::cameras_changed).
template <class Scalar>
GaussianScene<Scalar> reconstruct_and_bake(PipelineRun<Scalar>& run, const std::vector<TrainFrame<Scalar>>& frames,
                                           GaussianScene<Scalar> init, const TrainParams& tp, const std::string& dir,
                                           const std::string& key, const std::string& label,
                                           const std::function<void(Trainer<Scalar>&)>& after_step = {}) {
  namespace fs = std::filesystem;
  using reconstruction_detail::try_resume;
  const PipelineParams& p = run.params;
  fs::create_directories(dir);
  const std::string partial = (fs::path(dir) / "partial.bin").string();
  const std::string final_ckpt = (fs::path(dir) / "checkpoint.bin").string();
  Trainer<Scalar> trainer(frames, std::move(init), tp);
  if (try_resume(trainer, final_ckpt, key, label, run.log) && trainer.finished()) {
    run.log(label + ": training had finished; reusing its checkpoint");
  } else if (try_resume(trainer, partial, key, label, run.log)) {
    run.log(label + ": resuming at iteration " + std::to_string(trainer.iteration()));
  }
  if (after_step) after_step(trainer);  // once where training resumed, too
  const bool trained_now = !trainer.finished();
  bool floor_said = false;
  TrainingTimes times;
  while (!trainer.finished()) {
    const TrainProgress& pr = trainer.step();
    times.add(pr);
    const ShortcutState& sc = pr.shortcuts;
    if (pr.spared > 0 && !floor_said) {
      floor_said = true;
      run.log(label + ": densification at iteration " + std::to_string(pr.iteration) +
              " would have pruned the model below its floor of " + std::to_string(tp.densify_params.min_gaussians) +
              " Gaussians; the most opaque stay and training goes on (a background the frames do not share "
              "drives every opacity down; check --background)");
    }
    if (pr.iteration == trainer.still_check_iteration()) run.log(label + ": " + still_verdict_text(sc));
    if (sc.stopped)
      run.log(label + ": loss plateaued, training stopped at iteration " + std::to_string(pr.iteration) + " of " +
              std::to_string(tp.iterations));
    char detail[96];
    std::snprintf(detail, sizeof(detail), "psnr %.2f  %zu gaussians", pr.psnr, pr.gaussians);
    run.progress(label, pr.iteration, tp.iterations, detail);
    if (p.checkpoint_every > 0 && pr.iteration % p.checkpoint_every == 0 && !trainer.finished()) {
      trainer.save_checkpoint(partial);
      write_file_atomic(partial + ".key", key);
    }
    if (p.on_iteration) p.on_iteration(label, pr.iteration);
    if (after_step) after_step(trainer);
  }
  if (trained_now) {
    trainer.save_checkpoint(final_ckpt);
    write_file_atomic(final_ckpt + ".key", key);
  }
  const std::string record = (fs::path(dir) / "training.json").string();
  nlohmann::json training =
      training_json(trainer.shortcuts(), tp, trainer.still_check_iteration(), trainer.iteration(), times);
  if (!trained_now) training["timing"] = reconstruction_detail::recorded_timing(record);
  write_file_atomic(record, training.dump(1) + "\n");
  std::error_code ec;
  fs::remove(partial, ec);
  fs::remove(partial + ".key", ec);
  if (tp.deformable && trainer.field() && trainer.deforming_at(trainer.iteration())) {
    MedianBakeParams mp;
    mp.samples = p.median_samples;
    mp.threads = p.threads;
    FieldDeformation<Scalar> d(*trainer.field(), p.threads);
    return bake_median(trainer.scene(), d, mp);
  }
  return trainer.scene();
}

// The starting scene of a reconstruction: the sparse points the training source
// frames observed (PipelineInput: source_points), or, when there are too few, a
// random cloud in the training cameras' view volume.
template <class Scalar>
GaussianScene<Scalar> initial_scene(const PipelineRun<Scalar>& run, const std::vector<TrainFrame<Scalar>>& frames) {
  const auto& in = *run.input;
  InitParams ip;
  ip.seed = run.params.seed;
  const SourcePoints<Scalar> sp = source_points(in);
  if (sp.kept >= 4) return init_from_points(sp.points, sp.colors, ip);
  ip.random_points = run.params.init_points;
  return init_random(frame_cameras(frames), ip);
}

// Renders `scene` at the rendered canonical views into run.out/folder/NNNN.png
// and returns the written files (relative to run.out). Encoding a PNG costs a
// good fraction of a render (4-6 ms on one thread at 512x512), so views are
// rendered in batches (the renderer uses every thread) and each batch is
// encoded on all threads.
template <class Scalar>
std::vector<std::string> render_orbit_views(PipelineRun<Scalar>& run, const GaussianScene<Scalar>& scene,
                                            const std::string& folder, const std::string& label) {
  namespace fs = std::filesystem;
  using pipeline_detail::view_file;
  fs::create_directories(fs::path(run.out) / folder);
  Renderer<Scalar> r = run.renderer();
  const auto views = pipeline_detail::rendered_views(run.fit.views, run.params.render_stride);
  const int threads = resolve_threads(run.params.threads);
  const std::size_t batch = 2 * std::size_t(threads);
  std::vector<Image<Scalar>> images(std::min(batch, views.size()));
  std::vector<std::string> files;
  for (std::size_t first = 0; first < views.size(); first += batch) {
    const std::size_t n = std::min(batch, views.size() - first);
    for (std::size_t k = 0; k < n; ++k)
      images[k] = r.render(SceneView<Scalar>(scene), run.fit.cameras[std::size_t(views[first + k])]).color;
    parallel_for(n, threads, [&](std::size_t k, int) {
      write_png((fs::path(run.out) / folder / view_file(views[first + k])).string(), images[k]);
    });
    for (std::size_t k = 0; k < n; ++k) files.push_back(folder + "/" + view_file(views[first + k]));
    run.progress(label, int(first + n), int(views.size()));
  }
  return files;
}

// The files render_orbit_views writes, without rendering.
template <class Scalar>
std::vector<std::string> orbit_view_files(const PipelineRun<Scalar>& run, const std::string& folder) {
  std::vector<std::string> files;
  for (int v : pipeline_detail::rendered_views(run.fit.views, run.params.render_stride))
    files.push_back(folder + "/" + pipeline_detail::view_file(v));
  return files;
}

}  // namespace orbitforge
