"""setuptools front end of the CMake build (pyproject.toml): builds only the
`voxcast_python` target (python/voxcast_module.cpp and the library) in
build-pip and installs the module it produces."""

import glob
import os
import shutil
import subprocess
import sys

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

ROOT = os.path.dirname(os.path.abspath(__file__))
os.makedirs(os.path.join(ROOT, "build-pip"), exist_ok=True)  # egg_base must exist


class CMakeBuild(build_ext):
    def build_extension(self, ext):
        build = os.path.join(ROOT, "build-pip")  # CMake's
        jobs = os.environ.get("JOBS", str(os.cpu_count() or 1))
        subprocess.run(["cmake", "-S", ROOT, "-B", build, "-G", "Ninja",
                        "-DCMAKE_BUILD_TYPE=Release", "-DVOXCAST_BUILD_TESTS=OFF",
                        "-DVOXCAST_BUILD_BENCH=OFF", "-DVOXCAST_BUILD_PYTHON=ON",
                        # The interpreter pip runs: the module's ABI and site-packages.
                        "-DPYTHON_EXECUTABLE=" + sys.executable], check=True)
        subprocess.run(["cmake", "--build", build, "-j", jobs, "--target", "voxcast_python"],
                       check=True)
        built = glob.glob(os.path.join(build, "python", "voxcast*.so"))
        if len(built) != 1:
            raise RuntimeError("the CMake build produced %r, not one module" % built)
        target = self.get_ext_fullpath(ext.name)
        os.makedirs(os.path.dirname(target), exist_ok=True)
        shutil.copyfile(built[0], target)


# No Python packages to discover (src/ is C++), and setuptools' own build
# files beside CMake's in build-pip, not in the CMake build directory build/.
setup(ext_modules=[Extension("voxcast", sources=[])], cmdclass={"build_ext": CMakeBuild},
      packages=[], py_modules=[],
      options={"build": {"build_base": "build-pip/setuptools"},
               "egg_info": {"egg_base": "build-pip"}})
