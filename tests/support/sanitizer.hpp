#pragma once
// ORBITFORGE_TEST_SANITIZED is 1 under AddressSanitizer or ThreadSanitizer (GCC
// or clang): tests that cap RLIMIT_AS cannot run beside a sanitizer's shadow
// memory and skip there.
#ifndef ORBITFORGE_TEST_SANITIZED
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
#define ORBITFORGE_TEST_SANITIZED 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer)
#define ORBITFORGE_TEST_SANITIZED 1
#endif
#endif
#endif
