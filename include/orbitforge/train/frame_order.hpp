#pragma once
// The order frames are drawn in: passes over the frames, each frame drawn as
// often as its weight (TrainFrame::repeats), shuffled anew from the trainer's
// random generator at the start of every pass (3DGS pops cameras from a
// shuffled stack and refills it when empty).
#include <algorithm>
#include <cstddef>
#include <utility>
#include <vector>

#include "orbitforge/core/error.hpp"

namespace orbitforge {

class FrameOrder {
 public:
  FrameOrder() = default;
  // repeats[i]: draws of frame i per pass (>= 1).
  explicit FrameOrder(std::vector<int> repeats) : repeats_(std::move(repeats)) {
    std::size_t draws = 0;
    for (int r : repeats_) draws += std::size_t(r);
    order_.resize(draws);
    cursor_ = order_.size();  // shuffle on first use
  }

  // The next frame index; a new pass (shuffled with `rng`) when this one is used up.
  template <class Rng>
  std::size_t next(Rng& rng) {
    if (cursor_ >= order_.size()) {
      std::size_t k = 0;
      for (std::size_t i = 0; i < repeats_.size(); ++i)
        for (int r = 0; r < repeats_[i]; ++r) order_[k++] = i;
      std::shuffle(order_.begin(), order_.end(), rng);
      cursor_ = 0;
    }
    return order_[cursor_++];
  }

  // Draws per pass.
  std::size_t pass_length() const { return order_.size(); }
  // Draws left in the current pass, counting the one next() returned last.
  std::size_t remaining_with_last() const { return order_.size() - cursor_ + 1; }

  // The state a checkpoint keeps: the current pass and the position in it.
  const std::vector<std::size_t>& order() const { return order_; }
  std::size_t cursor() const { return cursor_; }
  // Refuses an order of another length (other frames or weights); nothing changes then.
  void restore(std::vector<std::size_t> order, std::size_t cursor) {
    ensure(order.size() == order_.size(), "checkpoint: a frame order of ", order.size(),
           " draws, this trainer's has ", order_.size());
    order_ = std::move(order);
    cursor_ = cursor;
  }

 private:
  std::vector<int> repeats_;
  std::vector<std::size_t> order_;
  std::size_t cursor_ = 0;
};

}  // namespace orbitforge
