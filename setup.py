"""Build of pcmm's one optional compiled piece, ``pcmm.model._tree_dynamics`` (pcmm/compiled.py says
what it is and when it is used).  Everything else is in pyproject.toml.

It compiles against the ``pin`` wheel's own Pinocchio headers and library and ``cmeel-eigen``'s
Eigen headers (build requirements in pyproject.toml), so it needs only a C++ compiler here.  It
is optional: where it does not build (no compiler, a wheel without headers), pcmm installs
without it and runs its pure-Python right-hand side, with the same results.
"""
import sys
from pathlib import Path

import numpy
from setuptools import Extension, setup


def _cmeel_prefix() -> Path | None:
    """The ``cmeel.prefix`` folder holding Pinocchio's headers (in pip's build environment)."""
    for entry in sys.path:
        prefix = Path(entry) / "cmeel.prefix"
        if (prefix / "include" / "pinocchio" / "config.hpp").is_file():
            return prefix
    return None


prefix = _cmeel_prefix()
extensions = []
if prefix is None:
    print("pcmm: Pinocchio's headers were not found; building without pcmm.model._tree_dynamics", file=sys.stderr)
else:
    extensions.append(Extension(
        "pcmm.model._tree_dynamics",
        sources=["pcmm/model/_tree_dynamics.cpp"],
        language="c++",
        include_dirs=[str(prefix / "include"), str(prefix / "include" / "eigen3"), numpy.get_include()],
        library_dirs=[str(prefix / "lib")],
        libraries=["pinocchio_default"],
        # the library Pinocchio's own bindings load; found by its soname once pinocchio is imported
        # (pcmm.compiled imports it first), or beside an installed pcmm in site-packages
        extra_link_args=["-Wl,-rpath,$ORIGIN/../../cmeel.prefix/lib"],
        # the definitions the pin wheel's Pinocchio was built with (its CMake config's interface)
        define_macros=[("NDEBUG", None), ("PINOCCHIO_ENABLE_TEMPLATE_INSTANTIATION", None),
                       ("BOOST_MPL_LIMIT_LIST_SIZE", "30"), ("BOOST_MPL_LIMIT_VECTOR_SIZE", "30"),
                       ("BOOST_MPL_CFG_NO_PREPROCESSED_HEADERS", None), ("BOOST_FUSION_INVOKE_MAX_ARITY", "12")],
        # -g0: no debug information (Python's own CFLAGS carry -g: 83 MB of it for this one file)
        extra_compile_args=["-std=c++17", "-O2", "-w", "-g0"],
        optional=True,
    ))

setup(ext_modules=extensions)
