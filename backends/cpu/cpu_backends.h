// cpu_backends.h — registration entry points of the CPU backends.
#pragma once

namespace mbvh {
void register_cpu_scalar_backend();
}  // namespace mbvh
