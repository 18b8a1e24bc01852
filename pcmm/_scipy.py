"""The few compiled parts of scipy a run uses, loaded without their packages' ``__init__``.

A run needs LAPACK's ``dpotrf``/``dpotrs``/``dgesv`` (``scipy.linalg._flapack``), the driver of
Hairer's Fortran DOP853 (``scipy.integrate._ode``) and DOP853's tableau
(``scipy.integrate._ivp.dop853_coefficients``).  Importing them the ordinary way runs
``scipy/linalg/__init__.py`` and ``scipy/integrate/__init__.py``, which import scipy's array-API
layer (``scipy._lib._array_api``: it touches every numpy submodule, numpy.f2py and numpy.testing
included), scipy.optimize, scipy.special and scipy.sparse: about 0.6 s of CPU at every start, a
hundred times Example 1's run (benchmarks/startup.py).

So each part is loaded from its own file under its own full name (``scipy.linalg._flapack``,
...), and registered in ``sys.modules`` under it: a later ordinary ``import scipy.linalg`` (a
study, a view, pcmm's loops) runs the package's ``__init__``, which finds these modules already
loaded and uses the very same objects.  A part that imports its siblings relatively (the
``ode`` driver) is loaded while its package stands in ``sys.modules`` as a bare path (no
``__init__`` run), removed again at once.  Wherever this fails (another scipy layout), the
ordinary import is used.
"""
from __future__ import annotations

import functools
import importlib
import importlib.machinery
import importlib.util
import sys
import types
from pathlib import Path


def _package_dir(package: str) -> Path:
    """The folder of a scipy subpackage, found without importing it (scipy's own ``__init__``,
    which is cheap, is not run either)."""
    top = importlib.util.find_spec("scipy")
    if top is None or not top.submodule_search_locations:
        raise ImportError("scipy is not installed")
    return Path(top.submodule_search_locations[0]).joinpath(*package.split(".")[1:])


def _file_of(package: str, name: str) -> Path:
    folder = _package_dir(package)
    for suffix in (*importlib.machinery.EXTENSION_SUFFIXES, ".py"):
        path = folder / (name + suffix)
        if path.is_file():
            return path
    raise ImportError(f"{package}.{name}: no file in {folder}")


def _exec(fullname: str, path: Path) -> types.ModuleType:
    spec = importlib.util.spec_from_file_location(fullname, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[fullname] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        sys.modules.pop(fullname, None)
        raise
    return module


def submodule(package: str, name: str, siblings: tuple[str, ...] = ()) -> types.ModuleType:
    """``package.name`` (a scipy submodule), loaded without running ``package``'s ``__init__``
    when that has not run yet; the ordinary import otherwise, or where this fails.  ``siblings``:
    the compiled modules of ``package`` that it imports relatively (``from . import x``), loaded
    alone first and set on the bare package (else the relative import would import scipy itself,
    through ``__import__``)."""
    fullname = f"{package}.{name}"
    if fullname in sys.modules:
        return sys.modules[fullname]
    if package in sys.modules:
        return importlib.import_module(fullname)
    try:
        path = _file_of(package, name)
        stub = types.ModuleType(package)  # the package as a bare path, for relative imports
        stub.__path__ = [str(path.parent)]
        stub.__package__ = package
        for sibling in siblings:
            setattr(stub, sibling, submodule(package, sibling))
        sys.modules[package] = stub
        try:
            return _exec(fullname, path)
        finally:
            if sys.modules.get(package) is stub:
                del sys.modules[package]  # an ordinary import later runs the real __init__
    except (ImportError, OSError):
        return importlib.import_module(fullname)


@functools.cache
def lapack():
    """LAPACK of scipy's build (``scipy.linalg.lapack``'s ``dpotrf``, ``dpotrs``, ``dgesv``, ...:
    the same Fortran objects)."""
    return submodule("scipy.linalg", "_flapack")


@functools.cache
def ode():
    """``scipy.integrate.ode``, the driver of Hairer's Fortran DOP853."""
    return submodule("scipy.integrate", "_ode", siblings=("_vode", "_dop")).ode


@functools.cache
def dop853_coefficients():
    """The tableau of scipy's DOP853 (``C``, ``A``, ``B``, ``E3``, ``E5``, ``D``, the stages)."""
    return submodule("scipy.integrate._ivp", "dop853_coefficients")
