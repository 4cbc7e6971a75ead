// SPDX-License-Identifier: MIT
// tinybvh_backends.h — registers the `tinybvh` peer backend (built when tinybvh's header is found
// and the target is x86-64 with the SIMD kernels: MBVH_TINYBVH).
#pragma once

namespace mbvh {
void register_tinybvh_backend();
}  // namespace mbvh
