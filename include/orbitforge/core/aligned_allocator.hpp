#pragma once
// CacheAlignedAllocator<T>: a std::allocator that starts every block on a 64-byte
// cache line, for buffers that several threads write side by side.
//
// Why: the rasterizer's threads take tiles one at a time, so neighbouring tiles
// of a row are written by different threads. A 16-pixel tile row of a float
// plane is 64 bytes, one line, but only if the plane starts on a line; glibc's
// large blocks start 16 bytes past one, so every tile row shared a line with its
// neighbour's and the two threads took the line from each other at every row
// (an empty 896x512 frame: 3.8 ms on two threads against 1.3 ms on one;
// docs/benchmarks.md, "Image buffers on cache lines").
#include <cstddef>
#include <new>
#include <vector>

namespace orbitforge {

inline constexpr std::size_t kCacheLineBytes = 64;

template <class T>
struct CacheAlignedAllocator {
  using value_type = T;
  static constexpr std::align_val_t alignment{kCacheLineBytes > alignof(T) ? kCacheLineBytes : alignof(T)};

  CacheAlignedAllocator() noexcept = default;
  template <class U>
  CacheAlignedAllocator(const CacheAlignedAllocator<U>&) noexcept {}

  T* allocate(std::size_t n) {
    if (n > std::size_t(-1) / sizeof(T)) throw std::bad_array_new_length();
    return static_cast<T*>(::operator new(n * sizeof(T), alignment));
  }
  void deallocate(T* p, std::size_t) noexcept { ::operator delete(p, alignment); }

  template <class U>
  bool operator==(const CacheAlignedAllocator<U>&) const noexcept { return true; }
  template <class U>
  bool operator!=(const CacheAlignedAllocator<U>&) const noexcept { return false; }
};

// A std::vector whose data() starts on a cache line.
template <class T>
using cache_aligned_vector = std::vector<T, CacheAlignedAllocator<T>>;

}  // namespace orbitforge
