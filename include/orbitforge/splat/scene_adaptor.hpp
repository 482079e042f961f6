#pragma once
// The scene adaptor: how the renderer reads Gaussians it does not own.
//
// The renderer (project_scene, project_scene_vjp, Renderer::render/backward)
// reads a scene only through a const reference to an adaptor, so a host keeps
// its own storage (array of structs, double precision, a GPU mirror ...). An
// adaptor is any type with these members:
//
//   struct MyAdaptor {
//     using scalar_type = double;                        // float or double
//     static constexpr orbitforge::ScaleMode scale_mode  // what scale() returns:
//         = orbitforge::ScaleMode::log;                  //   log: log standard deviations
//                                                        //   activated: standard deviations
//                                                        //   (any sign; the covariance uses s^2)
//     std::size_t size() const;                          // number of Gaussians
//     int sh_degree() const;                             // 0 .. 3
//     void mean(std::size_t i, double out[3]) const;     // world position
//     void rotation(std::size_t i, double out[4]) const; // quaternion (w, x, y, z), any
//                                                        //   non-zero norm (normalised here)
//     void scale(std::size_t i, double out[3]) const;    // see scale_mode
//     double opacity_logit(std::size_t i) const;         // opacity = sigmoid(logit)
//     double sh(std::size_t i, int k, int c) const;      // coefficient k < (degree + 1)^2,
//                                                        //   colour channel c < 3
//   };
//
// Optionally, a hint that Gaussians first .. first + count - 1 are read soon
// (project_scene calls it a few SIMD batches ahead; it must not read anything,
// only prefetch, e.g. with __builtin_prefetch):
//     void prefetch(std::size_t first, std::size_t count) const;
//
// Optionally, where the coefficients lie in memory one Gaussian after another,
// Gaussian i's 3 (degree + 1)^2 values at sh_data() + 3 (degree + 1)^2 i, in
// the order of sh(i, k, c) at offset 3 k + c (as GaussianScene stores them):
//     const scalar_type* sh_data() const;
// The projection then transposes a batch's coefficients straight from there
// instead of reading them one sh() call at a time (at degree 3, 48 reads per
// Gaussian; bench_project: about a third of the projection's time).
//
// Gradients (Renderer::backward) are with respect to exactly what the adaptor
// returns: d/d(log scale) for ScaleMode::log, d/d(scale) for activated, d/d of
// the quaternion as returned (before normalisation), d/d(opacity logit).
// SceneView (splat/scene_view.hpp) adapts a GaussianScene; tests/splat/
// test_scene_adaptor.cpp and examples/host_adaptor.cpp write one over an array
// of structs in double precision.
//
// Every entry point checks its adaptor with check_scene_adaptor<Scene>(), which
// names the first missing or mistyped member in one static_assert message
// instead of a deep template backtrace.
#include <cstddef>
#include <type_traits>
#include <utility>

namespace orbitforge {

enum class ScaleMode { log, activated };

namespace adaptor_detail {

template <class...>
using void_t = void;

template <class T, class = void>
struct has_scalar_type : std::false_type {};
template <class T>
struct has_scalar_type<T, void_t<typename T::scalar_type>>
    : std::bool_constant<std::is_same<typename T::scalar_type, float>::value ||
                         std::is_same<typename T::scalar_type, double>::value> {};

template <class T, class = void>
struct has_prefetch : std::false_type {};
template <class T>
struct has_prefetch<T, void_t<decltype(std::declval<const T&>().prefetch(std::size_t(), std::size_t()))>>
    : std::true_type {};

template <class T, class = void>
struct has_sh_data : std::false_type {};
template <class T>
struct has_sh_data<T, void_t<decltype(std::declval<const T&>().sh_data())>>
    : std::is_same<decltype(std::declval<const T&>().sh_data()), const typename T::scalar_type*> {};

template <class T, class = void>
struct has_scale_mode : std::false_type {};
template <class T>
struct has_scale_mode<T, void_t<decltype(T::scale_mode)>>
    : std::is_same<std::remove_cv_t<decltype(T::scale_mode)>, ScaleMode> {};

template <class T, class = void>
struct has_size : std::false_type {};
template <class T>
struct has_size<T, void_t<decltype(std::declval<const T&>().size())>>
    : std::is_convertible<decltype(std::declval<const T&>().size()), std::size_t> {};

template <class T, class = void>
struct has_sh_degree : std::false_type {};
template <class T>
struct has_sh_degree<T, void_t<decltype(std::declval<const T&>().sh_degree())>>
    : std::is_convertible<decltype(std::declval<const T&>().sh_degree()), int> {};

// mean / rotation / scale(i, S*) with S the adaptor's scalar type.
#define ORBITFORGE_ADAPTOR_ARRAY_MEMBER(name)                                                                   \
  template <class T, class = void>                                                                            \
  struct has_##name : std::false_type {};                                                                     \
  template <class T>                                                                                          \
  struct has_##name<T, void_t<decltype(std::declval<const T&>().name(                                         \
                           std::size_t(0), std::declval<typename T::scalar_type*>()))>> : std::true_type {};
ORBITFORGE_ADAPTOR_ARRAY_MEMBER(mean)
ORBITFORGE_ADAPTOR_ARRAY_MEMBER(rotation)
ORBITFORGE_ADAPTOR_ARRAY_MEMBER(scale)
#undef ORBITFORGE_ADAPTOR_ARRAY_MEMBER

template <class T, class = void>
struct has_opacity_logit : std::false_type {};
template <class T>
struct has_opacity_logit<T, void_t<decltype(std::declval<const T&>().opacity_logit(std::size_t(0)))>>
    : std::is_convertible<decltype(std::declval<const T&>().opacity_logit(std::size_t(0))),
                          typename T::scalar_type> {};

template <class T, class = void>
struct has_sh : std::false_type {};
template <class T>
struct has_sh<T, void_t<decltype(std::declval<const T&>().sh(std::size_t(0), 0, 0))>>
    : std::is_convertible<decltype(std::declval<const T&>().sh(std::size_t(0), 0, 0)), typename T::scalar_type> {};

}  // namespace adaptor_detail

// Whether T satisfies the whole contract.
template <class T>
struct is_scene_adaptor
    : std::bool_constant<adaptor_detail::has_scalar_type<T>::value && adaptor_detail::has_scale_mode<T>::value &&
                         adaptor_detail::has_size<T>::value && adaptor_detail::has_sh_degree<T>::value &&
                         adaptor_detail::has_mean<T>::value && adaptor_detail::has_rotation<T>::value &&
                         adaptor_detail::has_scale<T>::value && adaptor_detail::has_opacity_logit<T>::value &&
                         adaptor_detail::has_sh<T>::value> {};
template <class T>
inline constexpr bool is_scene_adaptor_v = is_scene_adaptor<T>::value;

// One readable compile error per missing member (see the contract above).
template <class T>
constexpr bool check_scene_adaptor() {
  using namespace adaptor_detail;
  static_assert(has_scalar_type<T>::value,
                "scene adaptor: needs `using scalar_type = float;` (or double) (splat/scene_adaptor.hpp)");
  static_assert(has_scale_mode<T>::value,
                "scene adaptor: needs `static constexpr orbitforge::ScaleMode scale_mode = ...;` "
                "(log or activated) (splat/scene_adaptor.hpp)");
  static_assert(has_size<T>::value, "scene adaptor: needs `std::size_t size() const` (splat/scene_adaptor.hpp)");
  static_assert(has_sh_degree<T>::value, "scene adaptor: needs `int sh_degree() const` (splat/scene_adaptor.hpp)");
  static_assert(has_mean<T>::value,
                "scene adaptor: needs `void mean(std::size_t i, scalar_type out[3]) const` (splat/scene_adaptor.hpp)");
  static_assert(has_rotation<T>::value,
                "scene adaptor: needs `void rotation(std::size_t i, scalar_type out[4]) const` (w, x, y, z) "
                "(splat/scene_adaptor.hpp)");
  static_assert(has_scale<T>::value,
                "scene adaptor: needs `void scale(std::size_t i, scalar_type out[3]) const` (splat/scene_adaptor.hpp)");
  static_assert(has_opacity_logit<T>::value,
                "scene adaptor: needs `scalar_type opacity_logit(std::size_t i) const` (splat/scene_adaptor.hpp)");
  static_assert(has_sh<T>::value,
                "scene adaptor: needs `scalar_type sh(std::size_t i, int k, int c) const` (splat/scene_adaptor.hpp)");
  return true;
}

}  // namespace orbitforge
