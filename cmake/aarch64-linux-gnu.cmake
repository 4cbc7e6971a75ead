# SPDX-License-Identifier: MIT
# aarch64-linux-gnu.cmake — a CMake toolchain file for the portable build on 64-bit ARM Linux,
# cross-compiled on Debian 12 with its cross compiler (g++-aarch64-linux-gnu) and the target's
# libraries from the arm64 multiarch packages (libzstd-dev:arm64, zlib1g-dev:arm64); header-only
# packages (Catch2, CLI11, nlohmann-json) are the host's. The programs run under qemu-user
# (qemu-aarch64), which ctest and Catch's test discovery call through CMAKE_CROSSCOMPILING_EMULATOR.
#   cmake -S . -B build-aarch64 -DCMAKE_TOOLCHAIN_FILE=cmake/aarch64-linux-gnu.cmake \
#         -DMBVH_OPENCL=OFF -DMBVH_VULKAN=OFF -DMBVH_EMBREE=OFF -DMBVH_PYTHON=OFF
# (scripts/cross-aarch64 does that and runs the tracing tests.)
set(CMAKE_SYSTEM_NAME Linux)
set(CMAKE_SYSTEM_PROCESSOR aarch64)
set(CMAKE_C_COMPILER aarch64-linux-gnu-gcc)
set(CMAKE_CXX_COMPILER aarch64-linux-gnu-g++)
# -L: the target's dynamic loader and C/C++ runtime (Debian's cross packages put them there)
set(CMAKE_CROSSCOMPILING_EMULATOR qemu-aarch64 -L /usr/aarch64-linux-gnu)
# Programs are linked statically (MBVH_STATIC_LINK): under qemu-user 7.2 (Debian 12) a dynamically
# linked aarch64 program spins forever in its first pthread_create (a four-thread std::thread test
# does; the same program linked with -static runs), and every multi-threaded build and trace would hang.
set(MBVH_STATIC_LINK ON CACHE BOOL "" FORCE)
# The target's libraries and CMake packages: the multiarch directories (/usr/lib/aarch64-linux-gnu,
# found through CMAKE_LIBRARY_ARCHITECTURE) and the arch-independent ones under /usr; never a
# host program's library (find_library searches no x86-64 directory with this architecture).
set(CMAKE_LIBRARY_ARCHITECTURE aarch64-linux-gnu)
