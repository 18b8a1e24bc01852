"""Build of pcmm's one optional compiled piece, ``pcmm.model._tree_dynamics`` (pcmm/compiled.py says
what it is and when it is used).  Everything else is in pyproject.toml.

It compiles against the ``pin`` wheel's own Pinocchio headers and library and ``cmeel-eigen``'s
Eigen headers (build requirements in pyproject.toml), so it needs only a C++ compiler here.  It
is optional: where it does not build (no compiler, a wheel without headers), pcmm installs
without it and runs its pure-Python right-hand side, with the same results.
"""
import hashlib
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import numpy
from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext


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
        depends=["pcmm/model/_segment_loop.hpp", "pcmm/model/_loops.hpp", "pcmm/model/_impulse.hpp",
                 "pcmm/model/_locate.hpp", "pcmm/model/_holding.hpp", "pcmm/model/_guard_eval.hpp",
                 "pcmm/model/_series.hpp"],  # the compiled segment loop, loops, impulse, event location and holding forces, included by it
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
        extra_compile_args=["-std=c++17", "-O3", "-w", "-g0"],
        optional=True,
    ))

def _cache_folder() -> Path:
    """Where compiled extensions are kept between installs: ``$PCMM_BUILD_CACHE``, else the
    user's cache folder (``$XDG_CACHE_HOME/pcmm/extensions``)."""
    if os.environ.get("PCMM_BUILD_CACHE"):
        return Path(os.environ["PCMM_BUILD_CACHE"])
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "pcmm" / "extensions"


class CachedBuildExt(build_ext):
    """setuptools' build_ext with a content-keyed cache: an extension whose sources, headers'
    Pinocchio version, compiler, flags and Python ABI are those of an earlier build is copied
    from that build instead of compiled again (the README's second command would otherwise
    recompile, for a minute, what the first built).  ``PCMM_BUILD_CACHE=0`` turns it off."""

    def _key(self, ext) -> str:
        h = hashlib.sha256()
        for src in [*ext.sources, *ext.depends]:
            h.update(Path(src).read_bytes())
        config = prefix / "include" / "pinocchio" / "config.hpp" if prefix else None
        h.update(config.read_bytes() if config and config.is_file() else b"")
        compiler = self.compiler.compiler_cxx if hasattr(self.compiler, "compiler_cxx") else [""]
        try:
            h.update(subprocess.run([compiler[0], "--version"], capture_output=True, timeout=30).stdout)
        except (OSError, subprocess.SubprocessError, IndexError):
            h.update(b"unknown compiler")
        h.update(repr((ext.define_macros, ext.extra_compile_args, ext.extra_link_args, ext.libraries,
                       sysconfig.get_config_var("EXT_SUFFIX"), sys.version, numpy.__version__)).encode())
        return h.hexdigest()[:32]

    def build_extension(self, ext):
        if os.environ.get("PCMM_BUILD_CACHE") == "0":
            return super().build_extension(ext)
        target = Path(self.get_ext_fullpath(ext.name))
        cached = _cache_folder() / f"{ext.name}-{self._key(ext)}{sysconfig.get_config_var('EXT_SUFFIX')}"
        if cached.is_file():
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(cached, target)
            print(f"pcmm: {ext.name} taken from the build cache {cached} (not compiled again)", file=sys.stderr)
            return
        # a miss compiles, whatever the dates say: setuptools skips an extension whose output is newer
        # than its sources and depends, and that output (build/lib's, from other sources) would be
        # cached under this key - a stale module passed off as the new sources' build
        force, self.force = self.force, True
        try:
            super().build_extension(ext)
        finally:
            self.force = force
        if target.is_file():
            try:
                cached.parent.mkdir(parents=True, exist_ok=True)
                tmp = cached.with_name(cached.name + f".{os.getpid()}.tmp")
                shutil.copyfile(target, tmp)
                os.replace(tmp, cached)
            except OSError as exc:  # a read-only home: the build stands, only the cache is lost
                print(f"pcmm: the build cache {cached.parent} is not writable ({exc}); next install compiles again",
                      file=sys.stderr)


setup(ext_modules=extensions, cmdclass={"build_ext": CachedBuildExt})
