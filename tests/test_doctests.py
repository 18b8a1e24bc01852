"""The numpydoc examples of the public API run as tests (from the repository root, where the
examples' relative paths point)."""
from __future__ import annotations

import doctest
import importlib

import pytest

from builders import ROOT

MODULES = ["pcmm", "pcmm.scene.load", "pcmm.run.loop", "pcmm.scene.settings", "pcmm.results.trajectory"]


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name, monkeypatch):
    monkeypatch.chdir(ROOT)
    result = doctest.testmod(importlib.import_module(name), optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0, f"{name}: no docstring example found"
    assert result.failed == 0, f"{name}: {result.failed} of {result.attempted} docstring examples failed"
