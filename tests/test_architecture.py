"""The package's layering: every module sits in one layer and imports only from layers below it,
so the import graph has no cycle and no upward import (a lazy import inside a function counts
too).  The run loop uses a configuration's coordinates only through the Coordinates protocol."""
from __future__ import annotations

import ast
import re

import pytest

from builders import ROOT

PKG = ROOT / "pcmm"

# lowest first; a module may import only from strictly lower layers
LAYERS = [
    {"errors", "witness", "signals", "expressions"},
    {"schema", "outputs", "template"},
    {"urdf", "pinocchio_helpers", "compiled", "integrators", "trajectory"},
    {"settings", "summary"},
    {"spec"},
    {"derive"},
    {"scene", "forces", "coordinates"},
    {"variations"},
    {"configuration"},
    {"constraints", "contact", "cutting", "momentum", "assembly"},
    {"mechanism", "impulse", "guards", "contact_laws", "approach", "contact_faults"},
    {"events"},
    {"transitions"},
    {"holding", "checks"},
    {"simulate"},
    {"sweep_plan", "sweep_run"},
    {"sweep_table", "sweep_backends", "sweep_plots"},
    {"sweep"},
    {"replay_page"},
    {"replay", "plots"},
    {"cli"},
    {"__init__"},
]
LAYER = {m: i for i, layer in enumerate(LAYERS) for m in layer}


def _imports(path):
    """The pcmm modules ``path`` imports, anywhere in the file (lazy imports included)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom):
            if node.level == 1:  # from .x import y / from . import x
                out |= {node.module.split(".")[0]} if node.module else {a.name for a in node.names}
            elif node.module and node.module.split(".")[0] == "pcmm":
                parts = node.module.split(".")
                out |= {parts[1]} if len(parts) > 1 else {a.name for a in node.names}
        elif isinstance(node, ast.Import):
            out |= {a.name.split(".")[1] for a in node.names if a.name.startswith("pcmm.")}
    return out


MODULES = sorted(p.stem for p in PKG.glob("*.py"))


def test_every_module_has_a_layer():
    assert set(MODULES) == set(LAYER), "place each new module in LAYERS (and in the README's module table)"


# No exception: where a lower module needs a higher one (Trajectory.show/plot need the views,
# Scene.with_values the loader) the package's top level binds it in (pcmm/__init__.py).
@pytest.mark.parametrize("module", MODULES)
def test_no_upward_import(module):
    upward = {m for m in _imports(PKG / f"{module}.py") if m in LAYER and LAYER[m] >= LAYER[module]}
    assert not upward, f"pcmm.{module} (layer {LAYER[module]}) imports {sorted(upward)} from its own layer or above"


def test_the_run_loop_uses_only_the_coordinates_protocol():
    """Every ``coords.X`` in simulate.py is a member of pcmm.coordinates.Coordinates."""
    from pcmm.coordinates import Coordinates
    members = {n for n in dir(Coordinates) if not n.startswith("_")} | set(Coordinates.__annotations__)
    used = set(re.findall(r"\bcoords\.(\w+)", (PKG / "simulate.py").read_text()))
    assert used and used <= members, f"simulate.py reaches past the protocol: {sorted(used - members)}"


def test_both_coordinate_strategies_satisfy_the_protocol(tmp_path):
    import pcmm
    from pcmm.constraints import PartitionedCoordinates, TreeCoordinates
    from pcmm.coordinates import Coordinates
    from pcmm.mechanism import Mechanism
    tree = Mechanism(pcmm.load_scene(ROOT / "examples" / "three_bar.toml"))["config1"].coords
    loop = Mechanism(pcmm.load_scene(ROOT / "examples" / "double_folded.toml"))["config1"].coords
    assert isinstance(tree, TreeCoordinates) and isinstance(loop, PartitionedCoordinates)
    assert isinstance(tree, Coordinates) and isinstance(loop, Coordinates)
    assert tree.guards() == [] and len(loop.guards()) == 1  # the loop's singularity guard


def test_readme_module_table_names_every_module_and_its_test():
    text = (ROOT / "README.md").read_text()
    table = text[text.index("## How it works"):text.index("## Development")]
    for module in MODULES:
        if module == "__init__":
            continue
        assert f"`{module}.py`" in table, f"README's module table lacks {module}.py"
    for test in re.findall(r"`(tests/test_\w+\.py)`", table):
        assert (ROOT / test).is_file(), f"README names a missing test module {test}"
