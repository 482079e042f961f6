#pragma once
// The training checkpoint file format: everything a Trainer (train/trainer.hpp)
// needs to continue exactly where it stopped, as plain data.
//
// Layout (native endianness; binary_io's primitives, nn/binary_io.hpp):
//   tag "OFTRAIN5" + scalar size (u32)
//   iteration, budget (i32); frame count (u64); seed (u32); deformable (u8);
//   scene extent (Scalar); elapsed seconds (f64)
//   still-scene check: checked (u8), field baked (u8), the field's gain (f64);
//   plateau stop: window loss sum, previous and last window means (f64), stopped (u8)
//   scene: SH degree (i32), means, rotations, log_scales, opacity_logits, sh (arrays)
//   Adam of the Gaussians (6 groups, nn/adam.hpp's record)
//   random generator state (string); frame order (array of u64: a frame index per
//   draw, a frame repeated as often as it is weighted), cursor (u64)
//   densification statistics: gradient sums (f64), counts (u32), max radii (Scalar)
//   deformable and not baked only: the DeformationField record, then its Adam
//   per-frame exposure transforms (array of Scalar, 12 per frame; empty when off),
//   then, when not empty, their Adam
//   learned background logits (array of Scalar, 3; empty when off), then, when
//   not empty, their Adam
// A file adds binary_io's checksum trailer and is written atomically; a damaged,
// cut or extended file is refused before any of it is parsed.
//
// read_checkpoint checks the record's own consistency (sizes agree with the
// scene, the order indexes a cursor inside it); whether it fits a given trainer
// (budget, frames, seed, network) is the trainer's check.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <istream>
#include <memory>
#include <ostream>
#include <sstream>
#include <string>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/deform/deformation_field.hpp"
#include "orbitforge/io/atomic_file.hpp"
#include "orbitforge/nn/adam.hpp"
#include "orbitforge/nn/binary_io.hpp"
#include "orbitforge/splat/gaussians.hpp"

namespace orbitforge {

// What the still-scene check and the plateau stop decided so far
// (TrainParams::still_check_iterations, plateau_window): the trainer keeps it,
// reports it with every iteration and saves it in its checkpoint.
struct ShortcutState {
  bool still_checked = false;
  bool field_baked = false;  // the field was baked into the scene; training went on static
  double field_gain_db = 0;  // the deformed model's PSNR over its bake's on training frames
  double field_region_gain_db = 0;  // the same per image region, at the check's rank (still_check.hpp)
  std::int32_t field_region = 0;    // that region, row-major
  double plateau_sum = 0;    // the loss summed over the current window
  double plateau_previous = 0, plateau_last = 0;  // the last two windows' mean losses (0 before they exist)
  bool stopped = false;      // training ended on a plateau, before its budget
};

template <class Scalar>
struct TrainingCheckpoint {
  int iteration = 0;  // iterations done
  int budget = 0;     // the run's total (its schedules depend on it)
  std::uint64_t frame_count = 0;
  std::uint32_t seed = 0;
  bool deformable = false;
  Scalar extent = 0;
  double elapsed_s = 0;
  GaussianScene<Scalar> scene;
  Adam<Scalar> adam;
  std::string rng_state;  // std::mt19937 as operator<< writes it
  std::vector<std::size_t> order;
  std::uint64_t cursor = 0;
  std::vector<double> densify_grad_sum;
  std::vector<std::uint32_t> densify_count;
  std::vector<Scalar> densify_max_radius;
  ShortcutState shortcuts;  // field_baked: no field follows
  std::unique_ptr<DeformationField<Scalar>> field;  // deformable and not baked only
  Adam<Scalar> field_adam;
  std::vector<Scalar> exposure;  // train/frame_exposure.hpp's transforms; empty when off
  Adam<Scalar> exposure_adam;
  std::vector<Scalar> background;  // train/learned_background.hpp's logits; empty when off
  Adam<Scalar> background_adam;
};

namespace checkpoint_detail {
inline constexpr char kTag[9] = "OFTRAIN5";
}

template <class Scalar>
void write_checkpoint(std::ostream& os, const TrainingCheckpoint<Scalar>& c) {
  using namespace binary_io;
  ensure(!c.deformable || c.shortcuts.field_baked || c.field,
         "write_checkpoint: a deformable checkpoint without its deformation field");
  ensure(!c.shortcuts.field_baked || c.deformable, "write_checkpoint: a static checkpoint cannot have a baked field");
  write_tag(os, checkpoint_detail::kTag, sizeof(Scalar));
  write<std::int32_t>(os, c.iteration);
  write<std::int32_t>(os, c.budget);
  write<std::uint64_t>(os, c.frame_count);
  write<std::uint32_t>(os, c.seed);
  write<std::uint8_t>(os, c.deformable ? 1 : 0);
  write(os, c.extent);
  write(os, c.elapsed_s);
  write<std::uint8_t>(os, c.shortcuts.still_checked ? 1 : 0);
  write<std::uint8_t>(os, c.shortcuts.field_baked ? 1 : 0);
  write(os, c.shortcuts.field_gain_db);
  write(os, c.shortcuts.field_region_gain_db);
  write<std::int32_t>(os, c.shortcuts.field_region);
  write(os, c.shortcuts.plateau_sum);
  write(os, c.shortcuts.plateau_previous);
  write(os, c.shortcuts.plateau_last);
  write<std::uint8_t>(os, c.shortcuts.stopped ? 1 : 0);
  const GaussianScene<Scalar>& s = c.scene;
  write<std::int32_t>(os, s.sh_degree);
  write_array(os, s.means.data(), s.means.size());
  write_array(os, s.rotations.data(), s.rotations.size());
  write_array(os, s.log_scales.data(), s.log_scales.size());
  write_array(os, s.opacity_logits.data(), s.opacity_logits.size());
  write_array(os, s.sh.data(), s.sh.size());
  c.adam.save(os);
  write_string(os, c.rng_state);
  write_array(os, c.order.data(), c.order.size());
  write<std::uint64_t>(os, c.cursor);
  write_array(os, c.densify_grad_sum.data(), c.densify_grad_sum.size());
  write_array(os, c.densify_count.data(), c.densify_count.size());
  write_array(os, c.densify_max_radius.data(), c.densify_max_radius.size());
  if (c.deformable && !c.shortcuts.field_baked) {
    c.field->save(os);
    c.field_adam.save(os);
  }
  write_array(os, c.exposure.data(), c.exposure.size());
  if (!c.exposure.empty()) c.exposure_adam.save(os);
  write_array(os, c.background.data(), c.background.size());
  if (!c.background.empty()) c.background_adam.save(os);
  ensure(bool(os), "write_checkpoint: write failed");
}

// `adam_params` are the optimizers' settings (a record holds their state only).
template <class Scalar>
TrainingCheckpoint<Scalar> read_checkpoint(std::istream& is, const AdamParams& adam_params = {}) {
  using namespace binary_io;
  TrainingCheckpoint<Scalar> c;
  read_tag(is, checkpoint_detail::kTag, sizeof(Scalar));
  c.iteration = read<std::int32_t>(is, "iteration");
  c.budget = read<std::int32_t>(is, "iteration budget");
  c.frame_count = read<std::uint64_t>(is, "frame count");
  c.seed = read<std::uint32_t>(is, "seed");
  c.deformable = read<std::uint8_t>(is, "mode") != 0;
  ensure(c.iteration >= 0 && c.iteration <= c.budget, "checkpoint: iteration ", c.iteration, " outside the budget ",
         c.budget);
  c.extent = read<Scalar>(is, "extent");
  c.elapsed_s = read<double>(is, "elapsed");
  c.shortcuts.still_checked = read<std::uint8_t>(is, "still checked") != 0;
  c.shortcuts.field_baked = read<std::uint8_t>(is, "field baked") != 0;
  c.shortcuts.field_gain_db = read<double>(is, "field gain");
  c.shortcuts.field_region_gain_db = read<double>(is, "field region gain");
  c.shortcuts.field_region = read<std::int32_t>(is, "field region");
  c.shortcuts.plateau_sum = read<double>(is, "plateau sum");
  c.shortcuts.plateau_previous = read<double>(is, "plateau previous");
  c.shortcuts.plateau_last = read<double>(is, "plateau last");
  c.shortcuts.stopped = read<std::uint8_t>(is, "stopped") != 0;
  ensure(!c.shortcuts.field_baked || c.deformable, "checkpoint: a static model with a baked field");
  const ShortcutState& sc = c.shortcuts;
  for (double v : {sc.field_gain_db, sc.field_region_gain_db, sc.plateau_sum, sc.plateau_previous, sc.plateau_last})
    ensure(std::isfinite(v), "checkpoint: non-finite still-scene or plateau state");
  ensure(sc.field_region >= 0 && sc.field_region < 1024, "checkpoint: still-scene region ", sc.field_region,
         " out of range");
  GaussianScene<Scalar>& s = c.scene;
  s.sh_degree = read<std::int32_t>(is, "SH degree");
  s.means = read_array<Scalar>(is, "means");
  s.rotations = read_array<Scalar>(is, "rotations");
  s.log_scales = read_array<Scalar>(is, "log_scales");
  s.opacity_logits = read_array<Scalar>(is, "opacity_logits");
  s.sh = read_array<Scalar>(is, "sh");
  s.check_consistent();
  ensure(std::isfinite(double(c.extent)) && c.extent > Scalar(0) && std::isfinite(c.elapsed_s) && c.elapsed_s >= 0,
         "checkpoint: scene extent ", c.extent, " or elapsed time ", c.elapsed_s, " is not a finite positive number");
  for (const auto* v : {&s.means, &s.rotations, &s.log_scales, &s.opacity_logits, &s.sh})
    ensure(std::all_of(v->begin(), v->end(), [](Scalar x) { return std::isfinite(double(x)); }),
           "checkpoint: the scene holds non-finite values");
  c.adam = Adam<Scalar>(adam_params);
  c.adam.load(is);
  ensure(c.adam.group_count() == 6, "checkpoint: optimizer has ", c.adam.group_count(), " groups, expected 6");
  for (int g = 0; g < 6; ++g)
    ensure(c.adam.group(g).rows == s.size(), "checkpoint: optimizer group '", c.adam.group(g).name, "' has ",
           c.adam.group(g).rows, " rows for ", s.size(), " Gaussians");
  c.rng_state = read_string(is, "rng state");
  c.order = read_array<std::size_t>(is, "frame order");
  c.cursor = read<std::uint64_t>(is, "frame cursor");
  ensure(c.cursor <= c.order.size(), "checkpoint: frame cursor ", c.cursor, " past the order's ", c.order.size(),
         " draws");
  for (auto o : c.order) ensure(o < c.frame_count, "checkpoint: frame index ", o, " out of range");
  c.densify_grad_sum = read_array<double>(is, "densify grad_sum");
  c.densify_count = read_array<std::uint32_t>(is, "densify count");
  c.densify_max_radius = read_array<Scalar>(is, "densify max_radius");
  ensure(c.densify_grad_sum.size() == s.size() && c.densify_count.size() == s.size() &&
             c.densify_max_radius.size() == s.size(),
         "checkpoint: densification statistics do not match the scene");
  c.field_adam = Adam<Scalar>(adam_params);
  if (c.deformable && !c.shortcuts.field_baked) {
    c.field = std::make_unique<DeformationField<Scalar>>(DeformationField<Scalar>::load(is));
    c.field_adam.load(is);
    ensure(c.field_adam.group_count() == 1 && c.field_adam.group(0).rows == c.field->parameter_count(),
           "checkpoint: deformation optimizer does not match the network");
  }
  c.exposure = read_array<Scalar>(is, "exposure transforms");
  c.exposure_adam = Adam<Scalar>(adam_params);
  if (!c.exposure.empty()) {
    ensure(c.exposure.size() == c.frame_count * 12, "checkpoint: ", c.exposure.size(),
           " exposure values for ", c.frame_count, " frames (12 each)");
    c.exposure_adam.load(is);
    ensure(c.exposure_adam.group_count() == 1 && c.exposure_adam.group(0).size() == c.exposure.size(),
           "checkpoint: exposure optimizer does not match the transforms");
  }
  c.background = read_array<Scalar>(is, "background logits");
  c.background_adam = Adam<Scalar>(adam_params);
  if (!c.background.empty()) {
    ensure(c.background.size() == 3, "checkpoint: ", c.background.size(), " background values, not an RGB colour");
    c.background_adam.load(is);
    ensure(c.background_adam.group_count() == 1 && c.background_adam.group(0).size() == 3,
           "checkpoint: background optimizer does not match the colour");
  }
  return c;
}

// The file form: the record plus a checksum trailer, written atomically.
template <class Scalar>
void write_checkpoint_file(const std::string& path, const TrainingCheckpoint<Scalar>& c) {
  std::ostringstream os(std::ios::binary);
  write_checkpoint(os, c);
  std::string bytes = os.str();
  binary_io::append_checksum(bytes);
  write_file_atomic(path, bytes);
}

// Refuses a file whose checksum does not match before parsing any of it; errors
// name the file.
template <class Scalar>
TrainingCheckpoint<Scalar> read_checkpoint_file(const std::string& path, const AdamParams& adam_params = {}) {
  const std::string bytes = read_file_bytes(path);
  try {
    std::istringstream is(binary_io::checked_payload(bytes), std::ios::binary);
    return read_checkpoint<Scalar>(is, adam_params);
  } catch (const Error& e) {
    fail(path, ": ", e.what());
  }
}

}  // namespace orbitforge
