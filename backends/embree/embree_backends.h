// SPDX-License-Identifier: MIT
// embree_backends.h — registers the `embree` peer backend (built when Embree 3 is found).
#pragma once

namespace mbvh {
void register_embree_backend();
}  // namespace mbvh
