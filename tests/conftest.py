"""Fixtures of the pcmm test suite: scenes written into ``tmp_path`` by :mod:`builders`."""
from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

# Byte-code caches on, whatever the environment says: under PYTHONDONTWRITEBYTECODE=1 every xdist
# worker re-rewrites the asserts of every test module at collection (8.2 s instead of 2.9 s CPU
# per worker) and each of the suite's own Python processes (CLI runs, the docs' blocks, sweep
# workers) recompiles pcmm from source (a short `pcmm run`: 1.34 s instead of 1.04 s CPU).  The
# caches land in git-ignored __pycache__ folders.
sys.dont_write_bytecode = False
os.environ.pop("PYTHONDONTWRITEBYTECODE", None)

from builders import scene_doc, write_scene


@pytest.fixture
def make_scene(tmp_path):
    """``make_scene(urdfs={file: text}, **builders.scene_doc kwargs) -> Path`` of the scene file.

    ``configurations`` defaults to one configuration ``c1`` per URDF in order.
    """
    counter = {"n": 0}

    def make(urdfs: dict[str, str], configurations: dict[str, str] | None = None, **kw) -> Path:
        counter["n"] += 1
        if configurations is None:
            configurations = {f"c{i + 1}": f for i, f in enumerate(urdfs)}
        return write_scene(tmp_path / f"scene{counter['n']}", scene_doc(configurations, **kw), urdfs)
    return make


@pytest.fixture
def configuration(make_scene):
    """``configuration(urdfs, name="c1", **scene kwargs) -> (scene, Configuration)``."""
    import pcmm
    from pcmm.model.mechanism import Mechanism

    def build(urdfs, name="c1", **kw):
        scene = pcmm.load_scene(make_scene(urdfs, **kw))
        return scene, Mechanism(scene)[name]
    return build


@pytest.fixture(scope="session")
def shipped_run():
    """``shipped_run("three_bar.toml", t_end=0.2) -> (scene, Trajectory)``: a shipped example run
    once per test session (per xdist worker) for every test that reads the same run.  The
    trajectory is shared: read it, never change it."""
    import pcmm
    from builders import EXAMPLES

    runs: dict = {}

    def run(name: str, **options):
        key = (name, tuple(sorted(options.items())))
        if key not in runs:
            scene = pcmm.load_scene(EXAMPLES / name)
            runs[key] = (scene, pcmm.simulate(scene, pcmm.RunOptions(**options)))
        return runs[key]
    return run


def _wider_fixtures(item) -> set:
    """The fixtures of module, class or package scope that ``item`` uses (set up once for the
    tests of their module that use them)."""
    return {d for defs in item._fixtureinfo.name2fixturedefs.values() for d in defs
            if d.scope in ("module", "class", "package")}


def pytest_collection_modifyitems(config, items):
    """The ``slow`` tests first (in their order), except those that share a module-scoped
    fixture with another test (moved away from it, they would have it set up a second time).

    Under pytest-xdist (``-n auto --dist worksteal``) each worker runs its share in this order
    and an idle worker takes queued tests from the end of another's queue: with the long tests
    at the front, the last tests to run are short ones, so no worker still runs a long test
    while the other has nothing left to do."""
    users: dict = {}
    for it in items:
        for d in _wider_fixtures(it):
            users[d] = users.get(d, 0) + 1
    early = [it for it in items if it.get_closest_marker("slow") is not None
             and all(users[d] == 1 for d in _wider_fixtures(it))]
    if early:
        moved = {id(it) for it in early}
        items[:] = early + [it for it in items if id(it) not in moved]
