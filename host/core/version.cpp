// SPDX-License-Identifier: MIT
// version.cpp — mbvh::version(): the version of the library that was linked.
#include "mbvh/version.h"

namespace mbvh {
const char* version() { return MBVH_VERSION_STRING; }
}  // namespace mbvh
