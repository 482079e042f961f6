#pragma once
// A background colour learned with the scene (TrainParams::learned_background):
// one RGB colour behind every training render, fitted to what the Gaussians
// leave uncovered. It is the alternative to a colour chosen from the frames'
// borders and to a random colour per iteration; docs/real_photographs.md
// measures the three on a real backdrop.
//
// The colour is held as logits u, colour = sigmoid(u), so that it stays in
// (0, 1) whatever the steps do. The renderer gives d loss / d colour (the sum
// over pixels of the final transmittance times the colour's gradient,
// Renderer::background_gradient); the chain rule through the sigmoid gives
// d loss / d u = d loss / d colour * colour (1 - colour), and Adam steps u.
#include <algorithm>
#include <array>
#include <cmath>
#include <utility>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/nn/adam.hpp"
#include "orbitforge/train/background.hpp"
#include "orbitforge/train/train_params.hpp"

namespace orbitforge {

template <class Scalar>
class LearnedBackground {
 public:
  LearnedBackground() = default;  // off
  // Starts at `initial` (each channel clamped to [1e-3, 1 - 1e-3], where the
  // logit is finite), learned at rate lr.
  LearnedBackground(const std::array<double, 3>& initial, const AdamParams& adam, double lr) : adam_(adam) {
    ensure(lr > 0 && std::isfinite(lr), "LearnedBackground: the learning rate must be positive, got ", lr);
    for (double c : initial) {
      ensure(std::isfinite(c), "LearnedBackground: the initial colour must be finite");
      const double v = std::min(1.0 - 1e-3, std::max(1e-3, c));
      logits_.push_back(Scalar(std::log(v / (1 - v))));
    }
    adam_.add_group("background", 1, 3, Scalar(lr));
  }
  // From a checkpoint's state (checked against each other).
  LearnedBackground(std::vector<Scalar> logits, Adam<Scalar> adam) : logits_(std::move(logits)), adam_(std::move(adam)) {
    ensure(logits_.size() == 3, "LearnedBackground: ", logits_.size(), " values, not an RGB colour");
    for (Scalar u : logits_) ensure(std::isfinite(double(u)), "LearnedBackground: a logit is not finite");
    ensure(adam_.group_count() == 1 && adam_.group(0).size() == 3,
           "LearnedBackground: the optimizer state does not match one colour");
  }

  bool enabled() const { return !logits_.empty(); }
  const std::vector<Scalar>& logits() const { return logits_; }
  const Adam<Scalar>& optimizer() const { return adam_; }

  std::array<Scalar, 3> color() const {
    ensure(enabled(), "LearnedBackground::color: the background is not learned");
    std::array<Scalar, 3> c;
    for (std::size_t i = 0; i < 3; ++i) c[i] = Scalar(1) / (Scalar(1) + std::exp(-logits_[i]));
    return c;
  }

  // d loss / d logits from d loss / d colour.
  std::array<Scalar, 3> logit_gradient(const std::array<Scalar, 3>& v_color) const {
    const std::array<Scalar, 3> c = color();
    std::array<Scalar, 3> v;
    for (std::size_t i = 0; i < 3; ++i) v[i] = v_color[i] * c[i] * (Scalar(1) - c[i]);
    return v;
  }

  // One Adam step along the render's d loss / d colour.
  void step(const std::array<Scalar, 3>& v_color) {
    const std::array<Scalar, 3> v = logit_gradient(v_color);
    adam_.step(0, logits_.data(), v.data());
  }

 private:
  std::vector<Scalar> logits_;  // empty: off
  Adam<Scalar> adam_;
};

// The trainer's: learned from p.background when p.learned_background, else off.
// A random background colour per iteration and a learned one exclude each other.
template <class Scalar>
LearnedBackground<Scalar> learned_background_for(const TrainParams& p) {
  ensure(!(p.learned_background && p.random_background),
         "TrainParams: learned_background and random_background exclude each other");
  if (!p.learned_background) return {};
  return LearnedBackground<Scalar>(p.background, p.adam, p.background_lr);
}

// The colour of every render but a training render with a random background:
// the learned one when on, else p.background.
template <class Scalar>
std::array<Scalar, 3> resting_background(const LearnedBackground<Scalar>& b, const TrainParams& p) {
  return b.enabled() ? b.color() : background_color<Scalar>(p.background);
}

}  // namespace orbitforge
