"""Module paths that moved into the subpackages keep a one-line stand-in for one release."""
import importlib
import sys
import warnings


def moved(old: str, new: str):
    """Make ``old`` the module ``new``, with a DeprecationWarning naming the new path."""
    warnings.warn(f"{old} moved to {new}; the old path goes in the next release", DeprecationWarning, stacklevel=3)
    sys.modules[old] = module = importlib.import_module(new)
    return module
