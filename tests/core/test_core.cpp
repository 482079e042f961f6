#include <catch2/catch.hpp>

#include <fcntl.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <numeric>
#include <optional>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/core/huge_pages.hpp"
#include "orbitforge/core/image.hpp"
#include "orbitforge/core/parallel_for.hpp"
#include "orbitforge/core/simd.hpp"
#include "support/temp_dir.hpp"

using namespace orbitforge;

TEMPLATE_TEST_CASE("camera conventions round-trip", "[core][camera]", float, double) {
  using S = TestType;
  using Vec3 = Eigen::Matrix<S, 3, 1>;
  const S tol = std::is_same<S, float>::value ? S(1e-5) : S(1e-12);
  Intrinsics<S> k{S(500), S(510), S(320), S(240), 640, 480};
  const Vec3 eye(S(3), S(-1), S(2)), target(S(0.1), S(0.2), S(-0.3)), up(S(0), S(0), S(1));
  const auto cam = Camera<S>::look_at(eye, target, up, k);

  SECTION("look_at: centre, forward, orthonormal, no roll") {
    REQUIRE((cam.center() - eye).norm() < tol * 10);
    REQUIRE((cam.forward() - (target - eye).normalized()).norm() < tol);
    REQUIRE((cam.R * cam.R.transpose() - Eigen::Matrix<S, 3, 3>::Identity()).norm() < tol);
    REQUIRE(cam.R.determinant() == Approx(1).margin(tol));
    REQUIRE(std::abs(cam.right().dot(up)) < tol);  // no roll: x axis horizontal
    REQUIRE(cam.up().dot(up) > 0);
    // The target projects to the principal point.
    const auto px = cam.project(target);
    REQUIRE(px.x() == Approx(k.cx).margin(1e-3));
    REQUIRE(px.y() == Approx(k.cy).margin(1e-3));
  }
  SECTION("OpenGL camera-to-world round trip") {
    const auto gl = cam.to_opengl_camera_to_world();
    // OpenGL looks along -z.
    REQUIRE((-gl.template block<3, 1>(0, 2) - cam.forward()).norm() < tol);
    const auto back = Camera<S>::from_opengl_camera_to_world(gl, k);
    REQUIRE((back.R - cam.R).norm() < tol);
    REQUIRE((back.t - cam.t).norm() < tol * 10);
  }
  SECTION("world_T_camera inverts camera_T_world") {
    const Eigen::Matrix<S, 4, 4> m = cam.world_T_camera() * cam.camera_T_world();
    REQUIRE((m - Eigen::Matrix<S, 4, 4>::Identity()).norm() < tol * 10);
  }
  SECTION("resized intrinsics scale the principal point") {
    const auto k2 = k.resized(320, 240);
    REQUIRE(k2.fx == Approx(250));
    REQUIRE(k2.cy == Approx(120));
  }
  SECTION("degenerate look_at is an error") {
    REQUIRE_THROWS_AS(Camera<S>::look_at(eye, eye, up, k), Error);
    REQUIRE_THROWS_AS(Camera<S>::look_at(Vec3(0, 0, 5), Vec3(0, 0, 0), up, k), Error);
  }
}

TEST_CASE("parallel_for visits every index once and propagates errors", "[core][parallel]") {
  for (int threads : {1, 2, 4}) {
    std::vector<std::atomic<int>> hits(1000);
    parallel_for(hits.size(), threads, [&](std::size_t i, int worker) {
      REQUIRE(worker < threads);
      hits[i]++;
    });
    for (auto& h : hits) REQUIRE(h.load() == 1);
    REQUIRE_THROWS_AS(parallel_for(100, threads,
                                   [&](std::size_t i, int) {
                                     if (i == 57) throw Error("boom");
                                   }),
                      Error);
    // Nested use runs inline instead of deadlocking.
    std::atomic<int> total{0};
    parallel_for(8, threads, [&](std::size_t, int) { parallel_for(8, threads, [&](std::size_t, int) { total++; }); });
    REQUIRE(total.load() == 64);
  }
}

TEST_CASE("image indexing is row-major, channels fastest", "[core][image]") {
  Image<float> im(3, 2, 3);
  im(2, 1, 1) = 7.f;
  REQUIRE(im.data[(1 * 3 + 2) * 3 + 1] == 7.f);
  REQUIRE_THROWS_AS(Image<float>(-1, 2, 3), Error);
}

TEMPLATE_TEST_CASE("image planes start on a cache line, so threads writing neighbouring tiles share no line",
                   "[core][image]", float, double, std::int32_t) {
  // Sizes glibc serves from the heap and from mmap (whose blocks start 16 bytes past a line).
  for (int side : {3, 17, 512, 1024}) {
    Image<TestType> im(side, side, 3);
    REQUIRE(reinterpret_cast<std::uintptr_t>(im.data.data()) % kCacheLineBytes == 0);
    Image<TestType> copy = im;
    REQUIRE(reinterpret_cast<std::uintptr_t>(copy.data.data()) % kCacheLineBytes == 0);
    im.data.resize(im.data.size() + 1);
    REQUIRE(reinterpret_cast<std::uintptr_t>(im.data.data()) % kCacheLineBytes == 0);
  }
}

TEST_CASE("a program relaunches for huge pages only where the kernel gives them on request", "[core][huge_pages]") {
  REQUIRE(thp_mode("always [madvise] never") == "madvise");
  REQUIRE(thp_mode("[always] madvise never") == "always");
  REQUIRE(thp_mode("always madvise [never]") == "never");
  REQUIRE(thp_mode("") == "");
  REQUIRE(thp_mode("always madvise never") == "");

  const std::string madvise = "always [madvise] never\n";
  REQUIRE(huge_page_tunables(madvise, nullptr, nullptr) == std::optional<std::string>("glibc.malloc.hugetlb=1"));
  // The user's other tunables are kept, and the user's own choice of this one wins.
  REQUIRE(huge_page_tunables(madvise, "glibc.malloc.arena_max=2", nullptr) ==
          std::optional<std::string>("glibc.malloc.arena_max=2:glibc.malloc.hugetlb=1"));
  REQUIRE_FALSE(huge_page_tunables(madvise, "glibc.malloc.hugetlb=0", nullptr));
  // Set by the relaunch itself, so a relaunched program never relaunches again.
  REQUIRE_FALSE(huge_page_tunables(madvise, "glibc.malloc.hugetlb=1", nullptr));
  REQUIRE_FALSE(huge_page_tunables(madvise, nullptr, "0"));
  REQUIRE(huge_page_tunables(madvise, nullptr, "1"));
  // Huge pages already given to all memory, or never given: nothing to gain.
  REQUIRE_FALSE(huge_page_tunables("[always] madvise never", nullptr, nullptr));
  REQUIRE_FALSE(huge_page_tunables("always madvise [never]", nullptr, nullptr));
  REQUIRE_FALSE(huge_page_tunables("", nullptr, nullptr));
}

TEST_CASE("a run's record says which pages its heap gets", "[core][huge_pages]") {
  CHECK(hugetlb_tunable("glibc.malloc.hugetlb=1") == std::optional<std::string>("1"));
  CHECK(hugetlb_tunable("glibc.malloc.arena_max=2:glibc.malloc.hugetlb=0:glibc.malloc.tcache_count=0") ==
        std::optional<std::string>("0"));
  CHECK_FALSE(hugetlb_tunable("glibc.malloc.arena_max=2"));
  CHECK_FALSE(hugetlb_tunable(nullptr));
  const std::string madvise = "always [madvise] never\n";
  CHECK(huge_page_state("[always] madvise never", nullptr) == "2 MB pages (transparent huge pages: always)");
  CHECK(huge_page_state("always madvise [never]", "glibc.malloc.hugetlb=1") ==
        "4 KB pages (transparent huge pages: never)");
  CHECK(huge_page_state("", nullptr) == "unknown (no transparent huge page mode)");
  CHECK(huge_page_state(madvise, nullptr) == "4 KB pages (transparent huge pages: madvise; not requested)");
  CHECK(huge_page_state(madvise, "glibc.malloc.hugetlb=0") == huge_page_state(madvise, nullptr));
  // The tunable only counts where glibc's allocator reads it (not under a sanitizer).
  const std::string requested = huge_page_relaunch_built
                                    ? "2 MB pages on request (transparent huge pages: madvise; glibc.malloc.hugetlb=1)"
                                    : "4 KB pages (transparent huge pages: madvise; not requested)";
  CHECK(huge_page_state(madvise, "glibc.malloc.hugetlb=1") == requested);
  CHECK(huge_page_state(madvise, "glibc.malloc.arena_max=2:glibc.malloc.hugetlb=1:glibc.malloc.tcache_count=0") ==
        requested);
}

// The command line that runs the probe below: this test binary on the probe's hidden tag.
struct RelaunchProbeCommand {
  std::string self = std::filesystem::read_symlink("/proc/self/exe").string(), tag = "[.relaunch_probe]";
  std::vector<char*> argv{self.data(), tag.data(), nullptr};
  RelaunchProbeCommand() = default;
  RelaunchProbeCommand(const RelaunchProbeCommand&) = delete;  // argv points into this object
};

// Run by the next test in a process of its own: relaunches as a program would,
// then (in the relaunched process, or the same one where nothing relaunched)
// writes the GLIBC_TUNABLES it runs with, and huge_page_state(), on two lines to
// the file ORBITFORGE_TEST_PROBE_OUT names.
TEST_CASE("huge-page relaunch probe", "[.relaunch_probe]") {
  const char* out = std::getenv("ORBITFORGE_TEST_PROBE_OUT");
  if (out == nullptr) return;  // run by a tag filter that matched it, not by the test below
  RelaunchProbeCommand command;
  relaunch_with_huge_pages(command.argv.data());
  const char* tunables = std::getenv("GLIBC_TUNABLES");
  std::ofstream(out) << (tunables ? tunables : "") << "\n" << huge_page_state() << "\n";
}

TEST_CASE("a program relaunched for huge pages runs with glibc's tunable, once", "[core][huge_pages]") {
  if (!std::filesystem::exists("/proc/self/exe")) {
    WARN("SKIPPED: no /proc/self/exe");
    return;
  }
  orbitforge_test::TempDir dir("relaunch");
  const std::string out = dir.str("tunables.txt"), log = dir.str("probe.log");
  RelaunchProbeCommand command;
  // The child's environment: this one's, without the settings the test decides.
  std::vector<std::string> env_text{"ORBITFORGE_TEST_PROBE_OUT=" + out};
  for (char** e = environ; *e != nullptr; ++e) {
    const std::string entry = *e;
    if (entry.rfind("GLIBC_TUNABLES=", 0) != 0 && entry.rfind("ORBITFORGE_HUGE_PAGES=", 0) != 0 &&
        entry.rfind("ORBITFORGE_TEST_PROBE_OUT=", 0) != 0)
      env_text.push_back(entry);
  }
  const auto run_probe = [&](const char* opt_out) {
    std::vector<std::string> text = env_text;
    if (opt_out) text.push_back(std::string("ORBITFORGE_HUGE_PAGES=") + opt_out);
    std::vector<char*> env;
    for (auto& t : text) env.push_back(t.data());
    env.push_back(nullptr);
    std::filesystem::remove(out);
    // The probe's Catch output goes to a log, shown if it fails.
    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_addopen(&actions, STDOUT_FILENO, log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    pid_t pid = 0;
    const int spawned = posix_spawn(&pid, command.self.c_str(), &actions, nullptr, command.argv.data(), env.data());
    posix_spawn_file_actions_destroy(&actions);
    REQUIRE(spawned == 0);
    int status = 0;
    REQUIRE(waitpid(pid, &status, 0) == pid);
    std::stringstream probe_log;
    probe_log << std::ifstream(log).rdbuf();
    INFO("probe output:\n" << probe_log.str());
    REQUIRE(WIFEXITED(status));
    REQUIRE(WEXITSTATUS(status) == 0);
    std::ifstream in(out);
    REQUIRE(in);
    std::pair<std::string, std::string> tunables_and_state;
    std::getline(in, tunables_and_state.first);
    std::getline(in, tunables_and_state.second);
    return tunables_and_state;
  };
  const std::string thp = thp_enabled_text();
  const bool expected = huge_page_relaunch_built && thp_mode(thp) == "madvise";
  INFO("transparent huge pages: " << thp << "; relaunch built: " << huge_page_relaunch_built);
  // The relaunched probe relaunches no further (its tunable is set), so it exits
  // and writes what it ran with.
  const auto relaunched = run_probe(nullptr), opted_out = run_probe("0");
  REQUIRE(relaunched.first == (expected ? "glibc.malloc.hugetlb=1" : ""));
  REQUIRE(opted_out.first.empty());
  // And each process's record says what it got.
  CHECK(relaunched.second.rfind(expected ? "2 MB pages on request" : huge_page_state(thp, nullptr), 0) == 0);
  CHECK(opted_out.second == huge_page_state(thp, nullptr));
}

TEMPLATE_TEST_CASE("simd::hadd_rows gives each row's lane sum, in row order", "[core][simd]", float, double) {
  using B = simd::native_batch<TestType>;
  constexpr std::size_t N = B::size;
  std::mt19937 rng(77);
  std::uniform_real_distribution<double> u(-1, 1);
  // Counts below, at and across the 16-row blocks of the AVX-512 float path.
  for (int count : {1, 2, 5, 10, 15, 16, 17, 33}) {
    std::vector<B> rows;
    std::vector<double> expected;
    for (int i = 0; i < count; ++i) {
      TestType lanes[N];
      double sum = 0;
      for (std::size_t l = 0; l < N; ++l) {
        lanes[l] = TestType(u(rng)) + TestType(10 * i);  // rows differ by far more than round-off
        sum += double(lanes[l]);
      }
      rows.push_back(B::load_unaligned(lanes));
      expected.push_back(sum);
    }
    std::vector<TestType> out(std::size_t(count), TestType(-1e30));
    simd::hadd_rows(rows.data(), count, out.data());
    for (int i = 0; i < count; ++i) {
      INFO("count " << count << " row " << i);
      CHECK(double(out[std::size_t(i)]) == Approx(expected[std::size_t(i)]).epsilon(1e-5).margin(1e-5));
    }
  }
}

TEMPLATE_TEST_CASE("simd::exp2_nonpositive is within 2 ulp of 2^x, the same on every path", "[core][simd]", float,
                   double) {
  using T = TestType;
  using B = simd::native_batch<T>;
  using S = simd::scalar_batch<T>;
  constexpr std::size_t N = B::size;
  const double ulp = double(std::numeric_limits<T>::epsilon());
  const double floor = std::is_same<T, float>::value ? -125 : -1021;
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(floor, 0);
  std::vector<T> xs;
  for (int i = 0; i < 200000; ++i) xs.push_back(T(u(rng)));
  // Near 0 and near the integers, where f = x - round(x) is +-1/2.
  for (int i = 0; i <= 20000; ++i) xs.push_back(T(-1e-3 * i));
  for (int n = 0; n < 30; ++n)
    for (double d : {-0.5, -0.4999999, -0.5000001, 0.0})
      if (n + d >= 0) xs.push_back(T(-(n + d)));
  while (xs.size() % N) xs.push_back(T(0));
  double worst = 0;
  for (std::size_t i = 0; i < xs.size(); i += N) {
    T out[N];
    simd::exp2_nonpositive(B::load_unaligned(&xs[i])).store_unaligned(out);
    for (std::size_t l = 0; l < N; ++l) {
      const T x = xs[i + l];
      const long double exact = std::exp2l((long double)x);
      const double rel = double(std::fabs(((long double)out[l] - exact) / exact));
      worst = std::max(worst, rel);
      INFO("x = " << x);
      REQUIRE(rel <= 2 * ulp);
      REQUIRE(out[l] == simd::exp2_nonpositive(S(x)).v);  // scalar kernels give the same bits
    }
  }
  INFO("worst relative error " << worst / ulp << " ulp");
  CHECK(worst > 0);
  CHECK(simd::exp2_nonpositive(S(T(0))).v == Approx(1).epsilon(2 * ulp));
  // Below the floor: 2^floor, tiny but normal and finite.
  const T tiny = simd::exp2_nonpositive(S(T(-5000))).v;
  CHECK(tiny > 0);
  CHECK(std::isnormal(tiny));
  CHECK(double(tiny) == Approx(std::exp2(floor)));
}

namespace {
// One expression over the whole operator vocabulary of core/simd.hpp, written
// once for any batch type: the scalar batch must compile it (the scalar build
// runs the same kernels) and give each native lane's value.
template <class B>
B every_operator(B x, B y) {
  using M = simd::mask_t<B>;
  B acc = x;
  acc += y;
  acc -= B(0.25) * x;
  acc *= y;
  acc /= (simd::abs(y) + B(1));
  acc = +acc - (-x) + x * y - x / (simd::abs(x) + B(2));
  const M lt = x < y, le = x <= y, gt = x > y, ge = x >= y, eq = x == x, ne = x != y;
  M m = ((lt & le) | (gt ^ ge)) & eq;
  m = m | ((ne && !lt) || ~gt);
  m = m ^ ((lt == le) != (gt == ge));
  acc = simd::select(m, acc, simd::fma(x, y, acc));
  return acc + simd::min(x, y) * simd::max(x, y) + simd::sqrt(simd::abs(x)) + simd::floor(x) + simd::ceil(y) +
         simd::exp(B(0.1) * y) + simd::log(simd::abs(x) + B(1)) + simd::round_nearest(B(3) * x);
}
}  // namespace

TEMPLATE_TEST_CASE("simd::scalar_batch has the batch operators and agrees with each native lane", "[core][simd]",
                   float, double) {
  using T = TestType;
  using B = simd::native_batch<T>;
  using S = simd::scalar_batch<T>;
  constexpr std::size_t N = B::size;
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-3, 3);
  int differing_lanes = 0;
  for (int rep = 0; rep < 200; ++rep) {
    T xs[N], ys[N], out[N];
    for (std::size_t l = 0; l < N; ++l) {
      xs[l] = T(u(rng));
      ys[l] = l % 3 == 0 ? xs[l] : T(u(rng));  // some equal pairs for == and !=
    }
    every_operator(B::load_unaligned(xs), B::load_unaligned(ys)).store_unaligned(out);
    for (std::size_t l = 0; l < N; ++l) {
      const T s = every_operator(S(xs[l]), S(ys[l])).v;
      INFO("x " << xs[l] << " y " << ys[l]);
      // exp and log are xsimd's on the vector path and std's on the scalar one.
      REQUIRE(double(s) == Approx(double(out[l])).epsilon(std::is_same<T, float>::value ? 1e-5 : 1e-12).margin(1e-6));
      if (xs[l] != ys[l]) ++differing_lanes;
    }
  }
  CHECK(differing_lanes > 0);
  // The masks' truth tables.
  using SM = simd::mask_t<S>;
  const SM t(true), f(false);
  CHECK((t ^ f).v);
  CHECK_FALSE((t ^ t).v);
  CHECK((!f).v);
  CHECK((t && t).v);
  CHECK_FALSE((t && f).v);
  CHECK((f || t).v);
  CHECK((t == t).v);
  CHECK((t != f).v);
}

TEMPLATE_TEST_CASE("simd::transpose_block moves every value to its transposed place, at any strides", "[core][simd]",
                   float, double) {
  using T = TestType;
  auto check = [](auto batch_tag, std::size_t in_stride, std::size_t out_stride) {
    using B = decltype(batch_tag);
    constexpr std::size_t N = B::size;
    std::vector<T> in(N * in_stride + 3), out(N * out_stride + 3, T(-1));
    for (std::size_t i = 0; i < in.size(); ++i) in[i] = T(i) + T(0.25);
    simd::transpose_block<B>(in.data() + 1, in_stride, out.data() + 2, out_stride);
    for (std::size_t i = 0; i < out.size(); ++i) {
      const std::size_t o = i - 2, c = o / out_stride, r = o % out_stride;
      const bool inside = i >= 2 && c < N && r < N;
      INFO("lanes " << N << ", strides " << in_stride << " / " << out_stride << ", output " << i);
      REQUIRE(out[i] == (inside ? in[1 + r * in_stride + c] : T(-1)));  // nothing written outside the block
    }
  };
  for (std::size_t in_stride : {std::size_t(simd::native_batch<T>::size), std::size_t(16), std::size_t(67)})
    for (std::size_t out_stride : {std::size_t(simd::native_batch<T>::size), std::size_t(16), std::size_t(48)}) {
      check(simd::native_batch<T>{}, in_stride, out_stride);
      check(simd::scalar_batch<T>{}, in_stride, out_stride);
    }
}
