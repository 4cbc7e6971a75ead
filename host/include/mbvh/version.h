// SPDX-License-Identifier: MIT
// version.h — mbvh's version: the one place it is written (CMakeLists.txt reads it from here).
// The macros are plain C too (mbvh/mbvh_c.h includes this header).
#pragma once

#define MBVH_VERSION_MAJOR 0
#define MBVH_VERSION_MINOR 2
#define MBVH_VERSION_PATCH 0
#define MBVH_VERSION_STRING "0.2.0"

#ifdef __cplusplus
namespace mbvh {
/// The library's version, "MAJOR.MINOR.PATCH" (MBVH_VERSION_STRING of the library that was linked).
const char* version();
}  // namespace mbvh
#endif
