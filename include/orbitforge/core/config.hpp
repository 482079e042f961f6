#pragma once
// The complete list of ORBITFORGE_* configuration macros. Everything else is a
// template parameter (precision, SIMD architecture, tile size) or a plain
// Params struct.
//
//   ORBITFORGE_NO_SIMD                 force the scalar kernels even where xsimd has
//                                      an architecture (also automatic when the
//                                      compiler has no SIMD flag set).
//   ORBITFORGE_NO_STB_IMPLEMENTATION   do not compile stb_image into io/image_io.hpp
//                                      (define it when the host program already
//                                      links an stb_image implementation).
//   ORBITFORGE_DEFAULT_THREADS         default worker count for parallel_for when a
//                                      caller passes 0 (default: hardware threads).

#ifndef ORBITFORGE_DEFAULT_THREADS
#define ORBITFORGE_DEFAULT_THREADS 0
#endif
