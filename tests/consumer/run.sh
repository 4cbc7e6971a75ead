#!/usr/bin/env bash
# SPDX-License-Identifier: MIT
# run.sh BUILD WORK [SHARED_BUILD] — mbvh as a user gets it, each step must pass (SHARED_BUILD: a full
# build configured with -DBUILD_SHARED_LIBS=ON, whose install steps 1a and 1b check too):
#   1. full: `cmake --install BUILD` into WORK/full (static libraries unless BUILD set
#      BUILD_SHARED_LIBS), then examples/trace_scene.cpp built against it with
#      find_package(mbvh COMPONENTS cpu opencl vulkan embree) and mbvh::mbvh, and run;
#   1a. a CPU-only program from that full install: find_package(mbvh COMPONENTS cpu) and mbvh::cpu,
#      configured with OpenCL, Vulkan, Embree and TBB unfindable (a CPU-only program must not need
#      them), run; `ldd` shows no libOpenCL, libvulkan, libembree or libtbb (the installed program,
#      which links them, shows the check can see them);
#   1b. pkg-config: the example compiled with `g++ $(pkg-config --cflags mbvh)` (no -std flag of its
#      own: Cflags carry -std=c++20) and linked with plain `pkg-config --libs mbvh` (no --static,
#      static libraries), with `--libs --static mbvh`, and with `--libs mbvh-cpu` (whose binary
#      `ldd` shows no device library), each run;
#   1c. the C API, installed: libmbvh_c exports only mbvh_* functions; examples/trace_c.c built in
#      a C-only CMake project with find_package(mbvh COMPONENTS c) and run, and built with
#      `cc -std=c99 -pedantic -Werror $(pkg-config --cflags --libs mbvh_c)` and run (one shared
#      library: no C++ runtime or backend library on the C program's link line);
#   1p. the Python module, installed: the build's interpreter (Debian's /usr/bin/python3) imports it
#      from PREFIX/lib/python3.X/site-packages with PYTHONPATH and runs examples/trace_mesh.py;
#      `pip install --no-build-isolation .` packages the build (MBVH_BUILD_DIR) into a venv
#      made with --system-site-packages, whose python runs the example;
#   2. the core alone: a program including <mbvh/mbvh.h> builds against libmbvh_core only, and
#      the backends' registration calls are not declared there (they are <mbvh/backends.h>'s);
#   3. add_subdirectory, CPU-only, shared libraries: the consumer project adds mbvh's source tree
#      with OpenCL, Vulkan and Embree made unfindable (CMAKE_DISABLE_FIND_PACKAGE_*: AUTO must
#      build without them), without setting C++20 itself and without a build type (CMake's default for
#      a project that sets none: mbvh must build there and leave the consumer's empty; at -O0 the
#      step's compile of the whole library is also the short one), builds and runs the examples (C++, C);
#   4. CPU-only find_package: that build installed into WORK/cpu (shared libraries), the examples
#      built against it with find_package(mbvh COMPONENTS cpu) and mbvh::cpu (the README's way) and
#      run, `ldd` showing no device library; find_package(mbvh COMPONENTS opencl) must fail there
#      with a message naming the missing component; the example built with
#      `g++ $(pkg-config --cflags --libs mbvh)` from the shared install and run.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
BUILD="$(cd "$1" && pwd)"
WORK="$2"
SHARED_BUILD="${3:+$(cd "$3" && pwd)}"
rm -rf "$WORK"
mkdir -p "$WORK"
CONSUMER="$ROOT/tests/consumer"
passed=0
step() { echo "== consumer: $*"; }
ok() { echo "PASS: $*"; passed=$((passed + 1)); }
pc() { PKG_CONFIG_PATH="$1/lib/pkgconfig" pkg-config "${@:2}"; }  # PREFIX ARGS: pkg-config on PREFIX's .pc files
# the libraries a CPU-only program must not load (ldd lists what its libraries load too: Embree's TBB)
device_libs="libOpenCL|libvulkan|libembree|libtbb|libmpi"
no_device_libs() {  # BINARY WHAT
  local libs
  libs="$(ldd "$1")"
  if grep -E "$device_libs" <<<"$libs"; then
    echo "error: $2 loads the device libraries above; a CPU-only program (mbvh::cpu, mbvh-cpu.pc) must load no" \
         "OpenCL, Vulkan, Embree or TBB library" >&2
    exit 1
  fi
}

step "install the full build into $WORK/full"
cmake --install "$BUILD" --prefix "$WORK/full" >/dev/null
for f in include/mbvh/mbvh.h include/mbvh/mbvh_c.h include/mbvh/config.h lib/cmake/mbvh/mbvhConfig.cmake lib/pkgconfig/mbvh.pc \
         lib/pkgconfig/mbvh_c.pc lib/libmbvh_c.so bin/mbvh; do
  [ -e "$WORK/full/$f" ] || { echo "error: $WORK/full/$f was not installed" >&2; exit 1; }
done
# Outputs are captured before grep reads them: `cmd | grep -q` under pipefail fails at random when
# grep exits at its first match and cmd is killed by SIGPIPE writing the rest.
installed="$(ls "$WORK/full/include/mbvh")"
if grep -qE "traverse|layouts|intersect" <<<"$installed"; then
  echo "error: private headers were installed: $(ls "$WORK/full/include/mbvh")" >&2
  exit 1
fi
cmake -S "$CONSUMER" -B "$WORK/full-consumer" -G Ninja -DCMAKE_BUILD_TYPE=Release \
  -DCMAKE_PREFIX_PATH="$WORK/full" "-DMBVH_COMPONENTS=cpu;opencl;vulkan;embree" >/dev/null
cmake --build "$WORK/full-consumer" >/dev/null
"$WORK/full-consumer/trace_scene"
"$WORK/full-consumer/trace_c"
ok "find_package(mbvh COMPONENTS cpu opencl vulkan embree) and mbvh::mbvh from an install"
"$WORK/full/bin/mbvh" --version

# mbvh::mpi, asked for: find_package(mbvh COMPONENTS cpu mpi) finds MPI itself; examples/mpi_trace.cpp
# on 2 ranks of this host (the settings of cmake/mpi_tests.cmake)
if [ -e "$WORK/full/lib/cmake/mbvh/mbvhMpiTargets.cmake" ]; then
  step "mbvh::mpi from the install: find_package(mbvh COMPONENTS cpu mpi), examples/mpi_trace.cpp on 2 ranks"
  cmake -S "$CONSUMER" -B "$WORK/mpi-consumer" -G Ninja -DCMAKE_BUILD_TYPE=Release -DCMAKE_PREFIX_PATH="$WORK/full" \
    "-DMBVH_COMPONENTS=cpu;mpi" -DMBVH_TARGET=mbvh::cpu -DMBVH_WITH_C=OFF -DMBVH_WITH_MPI=ON >/dev/null
  cmake --build "$WORK/mpi-consumer" >/dev/null
  OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 OMPI_MCA_btl=self,vader \
    OMPI_MCA_btl_vader_single_copy_mechanism=none OMPI_MCA_rmaps_base_oversubscribe=1 \
    mpirun -np 2 "$WORK/mpi-consumer/mpi_trace"
  ok "find_package(mbvh COMPONENTS cpu mpi) and mbvh::mpi from an install: examples/mpi_trace.cpp on 2 ranks"
fi

# full_install_checks PREFIX NAME: a CPU-only program, and pkg-config, from the full install at PREFIX
full_install_checks() {
  local prefix="$1" name="$2" m cflags
  step "a CPU-only program from the $name install: find_package(mbvh COMPONENTS cpu), mbvh::cpu"
  # linked with --no-as-needed (some toolchains drop unused libraries by default): ldd then shows
  # every library the link line named
  if ! cmake -S "$CONSUMER" -B "$WORK/$name-cpu-only" -G Ninja -DCMAKE_BUILD_TYPE=Release -DCMAKE_PREFIX_PATH="$prefix" \
         -DCMAKE_EXE_LINKER_FLAGS=-Wl,--no-as-needed \
         -DMBVH_COMPONENTS=cpu -DMBVH_TARGET=mbvh::cpu -DMBVH_WITH_C=OFF -DCMAKE_DISABLE_FIND_PACKAGE_OpenCL=ON \
         -DCMAKE_DISABLE_FIND_PACKAGE_Vulkan=ON -DCMAKE_DISABLE_FIND_PACKAGE_embree=ON -DCMAKE_DISABLE_FIND_PACKAGE_TBB=ON \
         -DCMAKE_DISABLE_FIND_PACKAGE_MPI=ON > "$WORK/$name-cpu-only.log" 2>&1; then
    cat "$WORK/$name-cpu-only.log" >&2
    echo "error: find_package(mbvh COMPONENTS cpu) with mbvh::cpu needs OpenCL, Vulkan, Embree, TBB or MPI (above)" >&2
    exit 1
  fi
  cmake --build "$WORK/$name-cpu-only" >/dev/null
  "$WORK/$name-cpu-only/trace_scene"
  no_device_libs "$WORK/$name-cpu-only/trace_scene" "find_package(mbvh COMPONENTS cpu) + mbvh::cpu from the $name install"
  ok "find_package(mbvh COMPONENTS cpu) and mbvh::cpu from the $name install: no OpenCL, Vulkan, Embree, TBB or MPI needed or loaded"

  step "pkg-config from the $name install: mbvh, mbvh-cpu"
  pc "$prefix" --modversion mbvh
  for m in mbvh mbvh-cpu; do
    cflags="$(pc "$prefix" --cflags $m)"
    grep -q -- "-std=c++20" <<<"$cflags" || { echo "error: pkg-config --cflags $m lacks -std=c++20: $cflags" >&2; exit 1; }
  done
  # compiled once with the Cflags alone, linked three ways (the rpath finds shared libraries; a
  # no-op for static ones; --no-as-needed as above)
  # shellcheck disable=SC2046
  g++ -O1 -c -o "$WORK/$name-pc.o" "$ROOT/examples/trace_scene.cpp" $(pc "$prefix" --cflags mbvh)
  # shellcheck disable=SC2046
  g++ -o "$WORK/$name-pc" "$WORK/$name-pc.o" -Wl,--no-as-needed $(pc "$prefix" --libs mbvh) -Wl,-rpath,"$prefix/lib"
  "$WORK/$name-pc"
  if grep -qE "^#define MBVH_HAVE_(OPENCL|VULKAN|EMBREE) " "$prefix/include/mbvh/config.h"; then
    full_libs="$(ldd "$WORK/$name-pc")"  # every backend's libraries: the ldd checks can see them
    grep -qE "$device_libs" <<<"$full_libs" \
      || { echo "error: ldd shows no device library where the example links mbvh.pc: the ldd checks would see nothing" >&2; exit 1; }
  fi
  ok "g++ \$(pkg-config --cflags --libs mbvh) from the $name install: no -std flag of its own, no --static"
  # shellcheck disable=SC2046
  g++ -o "$WORK/$name-pc-static" "$WORK/$name-pc.o" $(pc "$prefix" --libs --static mbvh) -Wl,-rpath,"$prefix/lib"
  "$WORK/$name-pc-static"
  ok "pkg-config --libs --static mbvh from the $name install"
  # shellcheck disable=SC2046
  g++ -o "$WORK/$name-pc-cpu" "$WORK/$name-pc.o" -Wl,--no-as-needed $(pc "$prefix" --libs mbvh-cpu) -Wl,-rpath,"$prefix/lib"
  "$WORK/$name-pc-cpu"
  no_device_libs "$WORK/$name-pc-cpu" "the example linked with pkg-config --libs mbvh-cpu from the $name install"
  ok "pkg-config --libs mbvh-cpu from the $name install: no OpenCL, Vulkan, Embree or TBB loaded"
}
full_install_checks "$WORK/full" full
if [ -n "$SHARED_BUILD" ]; then
  step "install the full shared build $SHARED_BUILD into $WORK/full-shared"
  grep -qE "^BUILD_SHARED_LIBS:[A-Z]*=(ON|1|TRUE|YES)$" "$SHARED_BUILD/CMakeCache.txt" \
    || { echo "error: $SHARED_BUILD was not configured with -DBUILD_SHARED_LIBS=ON" >&2; exit 1; }
  cmake --install "$SHARED_BUILD" --prefix "$WORK/full-shared" >/dev/null
  full_install_checks "$WORK/full-shared" full-shared
fi

step "the C API from the install: a C-only project, pkg-config mbvh_c"
# the library exports the C API's functions and nothing of the C++ library inside it
exported="$(nm -D --defined-only "$WORK/full/lib/libmbvh_c.so" | awk '$2 ~ /^[TDBRVWi]$/ {print $3}')"
grep -q "^mbvh_trace$" <<<"$exported" || { echo "error: libmbvh_c.so does not export mbvh_trace" >&2; exit 1; }
if grep -v "^mbvh_" <<<"$exported"; then
  echo "error: libmbvh_c.so exports the symbols above, which are not the C API's (bindings/c/mbvh_c.map)" >&2
  exit 1
fi
cmake -S "$CONSUMER/c" -B "$WORK/c-consumer" -G Ninja -DCMAKE_BUILD_TYPE=Release -DCMAKE_PREFIX_PATH="$WORK/full" >/dev/null
cmake --build "$WORK/c-consumer" >/dev/null
"$WORK/c-consumer/trace_c"
ok "find_package(mbvh COMPONENTS c) in a C-only project from an install"
# shellcheck disable=SC2046
cc -std=c99 -pedantic -Wall -Wextra -Werror -O1 -o "$WORK/pc-example-c" "$ROOT/examples/trace_c.c" \
  $(PKG_CONFIG_PATH="$WORK/full/lib/pkgconfig" pkg-config --cflags --libs mbvh_c) -Wl,-rpath,"$WORK/full/lib"
"$WORK/pc-example-c"
ok "cc -std=c99 \$(pkg-config --cflags --libs mbvh_c)"

step "the Python module from the install, and packaged by pip into a venv"
py="$(sed -n 's/^Python3_EXECUTABLE:[A-Z]*=//p' "$BUILD/CMakeCache.txt")"
if ! compgen -G "$BUILD/python/mbvh/_mbvh*.so" >/dev/null || [ -z "$py" ]; then
  echo "error: $BUILD has no Python module (MBVH_PYTHON; Debian: python3-dev pybind11-dev)" >&2
  exit 1
fi
site="$(compgen -G "$WORK/full/lib/python3*/site-packages")"
run_example() {  # PYTHON: examples/trace_mesh.py on the bunny, five hits
  "$1" "$ROOT/examples/trace_mesh.py" "$ROOT/../shared/scenes/bun_zipper.ply.zst" > "$WORK/py.out"
  [ "$(grep -c '^ray [0-4]: triangle ' "$WORK/py.out")" = 5 ] || { cat "$WORK/py.out" >&2; exit 1; }
}
(cd "$WORK" && PYTHONPATH="$site" "$py" -c "import mbvh, sys; sys.exit(not mbvh.__file__.startswith('$site'))")
(cd "$WORK" && PYTHONPATH="$site" run_example "$py")
ok "$py imports mbvh from the install (PYTHONPATH=${site#"$WORK/full/"})"
"$py" -m venv --system-site-packages "$WORK/venv"
MBVH_BUILD_DIR="$BUILD" "$WORK/venv/bin/pip" install -q --no-build-isolation "$ROOT" > "$WORK/pip.log" 2>&1 \
  || { cat "$WORK/pip.log" >&2; exit 1; }
(cd "$WORK" && "$WORK/venv/bin/python" -c "import mbvh, sys; sys.exit(not mbvh.__file__.startswith('$WORK/venv/'))")
(cd "$WORK" && run_example "$WORK/venv/bin/python")
ok "pip install --no-build-isolation . into a venv (the build packaged)"

step "the core alone: <mbvh/mbvh.h> declares only what mbvh::core defines"
cat > "$WORK/core-only.cpp" <<'EOF'
#include <mbvh/mbvh.h>
#include <cmath>
int main() {  // a build and the reference traversal, no backend registered
  mbvh::Scene scene;
  scene.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  scene.triangles = {{0, 1, 2}};
  const auto acc = mbvh::Accel::build(scene);
  const mbvh::Ray ray{0.25f, 0.25f, 1, 0, 0, 0, -1, INFINITY};
  mbvh::TraceOutput out;
  mbvh::trace_reference(*acc, {&ray, 1}, {}, out, 1);
  return out.hits[0].prim == 0 && mbvh::list_backends().empty() ? 0 : 1;
}
EOF
g++ -std=c++20 -O1 -I"$WORK/full/include" -o "$WORK/core-only" "$WORK/core-only.cpp" -L"$WORK/full/lib" -lmbvh_core \
  -lzstd -pthread
"$WORK/core-only"
printf '#include <mbvh/mbvh.h>\nint main() { mbvh::register_builtin_backends(); }\n' > "$WORK/core-register.cpp"
if g++ -std=c++20 -fsyntax-only -I"$WORK/full/include" "$WORK/core-register.cpp" 2>/dev/null; then
  echo "error: <mbvh/mbvh.h> declares register_builtin_backends, which mbvh::core does not define" >&2
  exit 1
fi
ok "the core alone: <mbvh/mbvh.h> built against mbvh_core only; the registration calls are <mbvh/backends.h>'s"

step "add_subdirectory, CPU-only (OpenCL, Vulkan, Embree unfindable), shared libraries"
cmake -S "$CONSUMER" -B "$WORK/sub" -G Ninja -DMBVH_SOURCE_DIR="$ROOT" \
  -DMBVH_INSTALL=ON -DBUILD_SHARED_LIBS=ON -DCMAKE_DISABLE_FIND_PACKAGE_OpenCL=ON -DCMAKE_DISABLE_FIND_PACKAGE_Vulkan=ON \
  -DCMAKE_DISABLE_FIND_PACKAGE_embree=ON `# and the library needs none of the program's, the tests' or Python's:` \
  -DCMAKE_DISABLE_FIND_PACKAGE_CLI11=ON -DCMAKE_DISABLE_FIND_PACKAGE_nlohmann_json=ON -DCMAKE_DISABLE_FIND_PACKAGE_ZLIB=ON \
  -DCMAKE_DISABLE_FIND_PACKAGE_Catch2=ON -DCMAKE_DISABLE_FIND_PACKAGE_Python3=ON -DCMAKE_DISABLE_FIND_PACKAGE_pybind11=ON \
  `# nor MPI (mbvh::mpi is the install's test above), nor the tinybvh peer (bench and check only, and a user's` \
  `# tree has no ../shared/peers beside it):` -DCMAKE_DISABLE_FIND_PACKAGE_MPI=ON -DMBVH_TINYBVH=OFF | tee "$WORK/sub-configure.log" | grep "mbvh:" || true
grep -q "the OPENCL backend is not built" "$WORK/sub-configure.log"
grep -q "the EMBREE backend is not built" "$WORK/sub-configure.log"
# nothing of mbvh's own leaks into the consumer's cache
if grep -qE "^CMAKE_CXX_STANDARD|^CMAKE_CXX_FLAGS:.*fp-contract|^CMAKE_BUILD_TYPE:STRING=." "$WORK/sub/CMakeCache.txt"; then
  echo "error: mbvh set the consumer's C++ standard, flags or build type in its cache" >&2
  exit 1
fi
cmake --build "$WORK/sub" >/dev/null
"$WORK/sub/trace_scene"
"$WORK/sub/trace_c"
# the program and the tests are not built for a consumer; the core library links no backend
[ ! -e "$WORK/sub/mbvh/mbvh" ] && [ ! -e "$WORK/sub/mbvh/mbvh-tests" ]
libs="$(ldd "$WORK/sub/trace_scene")"
grep -q "libmbvh_core.so" <<<"$libs" || { echo "error: the shared consumer does not link libmbvh_core.so: $libs" >&2; exit 1; }
if grep -qE "libOpenCL|libvulkan|libembree" <<<"$libs"; then
  echo "error: the CPU-only consumer links a device library" >&2
  exit 1
fi
ok "add_subdirectory, CPU-only, shared"

step "install the CPU-only build into $WORK/cpu"
cmake --install "$WORK/sub" --prefix "$WORK/cpu" >/dev/null
cmake -S "$CONSUMER" -B "$WORK/cpu-consumer" -G Ninja -DCMAKE_BUILD_TYPE=Release \
  -DCMAKE_PREFIX_PATH="$WORK/cpu" -DMBVH_COMPONENTS=cpu -DMBVH_TARGET=mbvh::cpu >/dev/null
cmake --build "$WORK/cpu-consumer" >/dev/null
LD_LIBRARY_PATH="$WORK/cpu/lib" "$WORK/cpu-consumer/trace_scene"
LD_LIBRARY_PATH="$WORK/cpu/lib" "$WORK/cpu-consumer/trace_c"
LD_LIBRARY_PATH="$WORK/cpu/lib" no_device_libs "$WORK/cpu-consumer/trace_scene" "mbvh::cpu from a CPU-only shared install"
if cmake -S "$CONSUMER" -B "$WORK/cpu-consumer-cl" -G Ninja -DCMAKE_PREFIX_PATH="$WORK/cpu" \
     -DMBVH_COMPONENTS=opencl > "$WORK/cl.log" 2>&1; then
  echo "error: find_package(mbvh COMPONENTS opencl) succeeded on a CPU-only install" >&2
  exit 1
fi
grep -q "no 'opencl' backend" "$WORK/cl.log"
ok "find_package(mbvh COMPONENTS cpu) and mbvh::cpu from a CPU-only shared install; opencl refused"
# shellcheck disable=SC2046
g++ -O1 -o "$WORK/pc-shared" "$ROOT/examples/trace_scene.cpp" $(pc "$WORK/cpu" --cflags --libs mbvh) \
  -Wl,-rpath,"$WORK/cpu/lib"
"$WORK/pc-shared"
ok "g++ \$(pkg-config --cflags --libs mbvh) from a shared install"
echo "consumer: $passed passed"
