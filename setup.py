# SPDX-License-Identifier: MIT
"""setup.py: the Python package mbvh for pip (pyproject.toml). The package's Python files come from
bindings/python/mbvh; its compiled part, mbvh._mbvh, is built by CMake (CMakeLists.txt, target
mbvh_python) for the interpreter pip runs, with the library and every backend whose packages are
found (OpenCL, Vulkan, Embree: AUTO), and no program, test or install rule.

Environment: CMAKE_ARGS, extra CMake arguments (e.g. "-DMBVH_VULKAN=OFF"); CMAKE_BUILD_PARALLEL_LEVEL,
build jobs (default: every core); MBVH_BUILD_DIR, an already configured mbvh build directory whose
module (configured for this interpreter) is built and packaged instead of configuring a new one.
"""
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

ROOT = Path(__file__).resolve().parent


def version() -> str:
    text = (ROOT / "host/include/mbvh/version.h").read_text()
    return re.search(r'#define MBVH_VERSION_STRING "([0-9.]+)"', text).group(1)


class CMakeExtension(Extension):
    def __init__(self, name: str) -> None:
        super().__init__(name, sources=[])


class CMakeBuild(build_ext):
    def build_extension(self, ext: Extension) -> None:
        target = Path(self.get_ext_fullpath(ext.name)).resolve()
        build_dir = os.environ.get("MBVH_BUILD_DIR")
        if build_dir:
            build = Path(build_dir).resolve()
            if not (build / "CMakeCache.txt").is_file():
                sys.exit(f"error: MBVH_BUILD_DIR={build_dir} is not a configured CMake build directory")
        else:
            build = Path(self.build_temp).resolve() / "cmake"
            build.mkdir(parents=True, exist_ok=True)
            args = ["-DCMAKE_BUILD_TYPE=Release", f"-DPython3_EXECUTABLE={sys.executable}", "-DMBVH_PYTHON=ON",
                    "-DMBVH_BUILD_TOOLS=OFF", "-DMBVH_BUILD_TESTS=OFF", "-DMBVH_BUILD_EXAMPLES=OFF",
                    "-DMBVH_INSTALL=OFF"]
            try:  # pybind11 from the package index (build isolation); else CMake finds Debian's pybind11-dev
                import pybind11
                args.append(f"-Dpybind11_DIR={pybind11.get_cmake_dir()}")
            except ImportError:
                pass
            if shutil.which("ninja"):
                args += ["-G", "Ninja"]
            args += shlex.split(os.environ.get("CMAKE_ARGS", ""))
            subprocess.run(["cmake", "-S", str(ROOT), "-B", str(build), *args], check=True)
        jobs = os.environ.get("CMAKE_BUILD_PARALLEL_LEVEL", str(os.cpu_count() or 1))
        subprocess.run(["cmake", "--build", str(build), "--target", "mbvh_python", "--parallel", jobs], check=True)
        built = sorted((build / "python" / "mbvh").glob("_mbvh*" + Path(target).suffix))
        if not built:
            sys.exit(f"error: the build made no module {build}/python/mbvh/_mbvh*{target.suffix} "
                     "(is MBVH_PYTHON off there, or Python 3's headers or pybind11 missing?)")
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(built[0], target)


setup(
    name="mbvh",
    version=version(),
    description="Exact BVH ray tracing (MBVH2/4/8, stackless bitstack traversal) on CPU SIMD, OpenCL and Vulkan",
    long_description=(ROOT / "README.md").read_text(),
    long_description_content_type="text/markdown",
    license="MIT",
    python_requires=">=3.8",
    install_requires=["numpy"],
    packages=["mbvh"],
    package_dir={"mbvh": "bindings/python/mbvh"},
    package_data={"mbvh": ["*.pyi", "py.typed"]},
    ext_modules=[CMakeExtension("mbvh._mbvh")],
    cmdclass={"build_ext": CMakeBuild},
    zip_safe=False,
    options={"build": {"build_base": "build-pip"}},  # beside the CMake build directories (/build-*/ is ignored)
)
