// SPDX-License-Identifier: MIT
// opencl_backends.h — the OpenCL backends' registration entry point.
#pragma once
#include <string>

namespace mbvh {

/// Registers `opencl`, `opencl-wide` and `opencl-lane` (opencl_backend.cpp).
void register_opencl_backends();

}  // namespace mbvh
