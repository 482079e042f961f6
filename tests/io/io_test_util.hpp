#pragma once
// Small helpers shared by the io tests: scratch folders, random cameras, and
// a check that an orbitforge::Error names what it should.
#include <catch2/catch.hpp>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <functional>
#include <sstream>
#include <initializer_list>
#include <random>
#include <string>
#include <vector>

#include <unistd.h>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/core/error.hpp"
#include "support/temp_dir.hpp"

namespace orbitforge_test {

// A per-process scratch folder <tmp>/orbitforge_test_<pid>/<tag>, the whole
// tree removed when the test program exits.
inline std::filesystem::path scratch_dir(const std::string& tag) {
  struct Root {
    std::filesystem::path path =
        std::filesystem::temp_directory_path() / ("orbitforge_test_" + std::to_string(::getpid()));
    ~Root() {
      std::error_code ignored;
      std::filesystem::remove_all(path, ignored);
    }
  };
  static Root root;
  const auto dir = root.path / tag;
  std::filesystem::create_directories(dir);
  return dir;
}

inline std::string slurp(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::ostringstream os;
  os << in.rdbuf();
  return os.str();
}

inline void spit(const std::filesystem::path& p, const std::string& bytes) {
  std::ofstream out(p, std::ios::binary);
  out << bytes;
}

// The message of the orbitforge::Error that f throws ("" when it throws none).
inline std::string error_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const orbitforge::Error& e) {
    return e.what();
  }
  return "";
}

// Runs f, requires an orbitforge::Error whose message contains every part.
template <class F>
void require_error(F&& f, std::initializer_list<std::string> parts) {
  bool thrown = false;
  std::string message;
  try {
    f();
  } catch (const orbitforge::Error& e) {
    thrown = true;
    message = e.what();
  }
  INFO("error message: " << message);
  REQUIRE(thrown);
  for (const auto& p : parts) {
    INFO("expected to contain: " << p);
    CHECK(message.find(p) != std::string::npos);
  }
}

// Cameras on a noisy ring looking at the origin, with varied intrinsics;
// names frame_001, frame_002, ... (already in name order).
template <class S>
std::vector<orbitforge::FrameCamera<S>> random_frame_cameras(int n, unsigned seed) {
  using V3 = Eigen::Matrix<S, 3, 1>;
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::vector<orbitforge::FrameCamera<S>> cams;
  for (int i = 0; i < n; ++i) {
    const double a = 2.0 * 3.141592653589793 * i / n;
    const V3 eye(S(3 * std::cos(a) + 0.2 * u(rng)), S(0.5 * u(rng)), S(3 * std::sin(a) + 0.2 * u(rng)));
    const V3 target(S(0.1 * u(rng)), S(0.1 * u(rng)), S(0.1 * u(rng)));
    orbitforge::Intrinsics<S> k;
    k.width = 320 + 16 * i;
    k.height = 240 + 8 * i;
    k.fx = S(300 + 50 * u(rng));
    k.fy = S(300 + 50 * u(rng));
    k.cx = S(0.5 * k.width + 3 * u(rng));
    k.cy = S(0.5 * k.height + 3 * u(rng));
    orbitforge::FrameCamera<S> f;
    char name[32];
    std::snprintf(name, sizeof(name), "frame_%03d.png", i + 1);
    f.name = name;
    f.camera = orbitforge::Camera<S>::look_at(eye, target, V3(0, 1, 0), k);
    cams.push_back(f);
  }
  return cams;
}

template <class S>
void require_same_cameras(const orbitforge::FrameCamera<S>& a, const orbitforge::FrameCamera<S>& b, double tol) {
  INFO("frame " << a.name);
  CHECK(a.name == b.name);
  CHECK(a.valid == b.valid);
  const auto& ka = a.camera.intrinsics;
  const auto& kb = b.camera.intrinsics;
  CHECK(ka.width == kb.width);
  CHECK(ka.height == kb.height);
  // Pixel quantities are ~300: compared relative to their size.
  auto close = [tol](double x, double y) { return std::abs(x - y) <= tol * std::max(1.0, std::abs(x)); };
  CHECK(close(ka.fx, kb.fx));
  CHECK(close(ka.fy, kb.fy));
  CHECK(close(ka.cx, kb.cx));
  CHECK(close(ka.cy, kb.cy));
  CHECK((a.camera.R - b.camera.R).cwiseAbs().maxCoeff() <= tol);
  // |t| is about 3.
  CHECK((a.camera.t - b.camera.t).cwiseAbs().maxCoeff() <= 4 * tol);
}

}  // namespace orbitforge_test
