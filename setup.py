"""Build the optional compiled kernel; everything else is in pyproject.toml.

``aobake._kernels`` moves the per-ray part of ray generation out of numpy, and the other
per-sample loops: one C file per stage (aobake/_kernels.c lists them and holds the module's
method table; aobake/_kernels.h what they share).  It needs only a C compiler and Python's
headers.  It is optional: if it cannot be built, the install still succeeds and aobake uses
the numpy formulation, which gives bit-identical results, only slower (the report records
which one ran).
"""

import sys

from setuptools import Extension, setup

# -ffp-contract=off: no fused multiply-add, so the kernel rounds exactly like numpy.
# -O3: the ray kernel's stage loops vectorise (measured 25 -> see docs/performance.md ns/ray).
FLAGS = [] if sys.platform == "win32" else ["-O3", "-ffp-contract=off", "-fno-fast-math"]
#: aobake._kernels's sources: the module's method table, then one file per stage
KERNELS = ["_kernels", "_rays", "_counts", "_raster", "_surface", "_seams", "_sparse", "_post",
           "_sort", "_pack", "_unionfind", "_normals", "_pixels", "_obj", "_orient"]

setup(
    ext_modules=[
        Extension("aobake._kernels", [f"aobake/{name}.c" for name in KERNELS],
                  depends=["aobake/_kernels.h"], extra_compile_args=FLAGS, optional=True),
        # Embree 4 occlusion packets on the libembree4 that embreex ships (aobake/_embree.c):
        # Embree's own headers for the types, the functions found with dlsym at run time, so
        # the build needs neither embreex nor an Embree install.  Optional: without it the
        # embree backend traces through embreex (the same hits, slower).
        *([] if sys.platform == "win32" else [
            Extension("aobake._embree", ["aobake/_embree.c"], include_dirs=["third_party/embree4"],
                      depends=["aobake/_kernels.h", "third_party/embree4/embree4/rtcore.h"], optional=True,
                      extra_compile_args=FLAGS, libraries=["dl"])]),
        # xatlas's charting with speed patches (third_party/xatlas/README.md): the same
        # charts as the xatlas package, which stays the fallback.  Flags as that package's
        # release build; -pthread for xatlas's task scheduler; no fused multiply-adds, for the
        # boundary sweep relies on linesIntersect giving the same bits in either order of its
        # edges (x86-64 without -march has no FMA: the package's bits either way).
        Extension("aobake._xatlas", ["aobake/_xatlas.cpp", "third_party/xatlas/xatlas.cpp"],
                  depends=["third_party/xatlas/xatlas.h"], include_dirs=["third_party/xatlas"],
                  language="c++", optional=True,
                  extra_compile_args=[] if sys.platform == "win32"
                  else ["-O3", "-DNDEBUG", "-std=c++17", "-fvisibility=hidden", "-pthread",
                        "-ffp-contract=off"],
                  extra_link_args=[] if sys.platform == "win32" else ["-pthread"]),
    ],
)
