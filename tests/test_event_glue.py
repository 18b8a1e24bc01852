"""The glue of a bounce cut in h-event4: each cut against the route it replaces."""
from __future__ import annotations

import os

import pytest

from pcmm.model import compiled


@pytest.mark.parametrize("value", [None, "0", "1", "", "00", " 0", "0 ", "no", "é"])
def test_enabled_reads_the_environment_as_os_environ_get(monkeypatch, value):
    """``compiled.enabled()`` reads PCMM_COMPILED from the environment's encoded dict: at every call,
    and with the same answer as ``os.environ.get(ENV, "1") != "0"`` (the route it replaces)."""
    if value is None:
        monkeypatch.delenv(compiled.ENV, raising=False)
    else:
        monkeypatch.setenv(compiled.ENV, value)
    want = compiled._tree_dynamics is not None and os.environ.get(compiled.ENV, "1") != "0"
    assert compiled.enabled() is want
    assert compiled.enabled() is (compiled._tree_dynamics is not None and value != "0")


def test_enabled_follows_a_change_of_the_environment(monkeypatch):
    if compiled._tree_dynamics is None:
        pytest.skip("no compiled extension in this tree")
    monkeypatch.setenv(compiled.ENV, "1")
    assert compiled.enabled()
    monkeypatch.setenv(compiled.ENV, "0")
    assert not compiled.enabled()
    monkeypatch.delenv(compiled.ENV)
    assert compiled.enabled()
    os.environ[compiled.ENV] = "0"  # (monkeypatch restores it)
    assert not compiled.enabled()
    del os.environ[compiled.ENV]
    assert compiled.enabled()
