#pragma once
// The library's version (semantic versioning); CMakeLists.txt's project()
// version is the same (a test checks it).
#define ORBITFORGE_VERSION_MAJOR 0
#define ORBITFORGE_VERSION_MINOR 2
#define ORBITFORGE_VERSION_PATCH 0
#define ORBITFORGE_VERSION_STRING "0.2.0"
// One number for #if comparisons: major * 10000 + minor * 100 + patch.
#define ORBITFORGE_VERSION (ORBITFORGE_VERSION_MAJOR * 10000 + ORBITFORGE_VERSION_MINOR * 100 + ORBITFORGE_VERSION_PATCH)
