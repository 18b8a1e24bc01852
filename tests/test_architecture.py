"""The package's layering, read from the package map in docs/architecture.md: every module sits in
one layer (a subpackage, or the base and top of the package's own folder) and imports only from
its own layer, the base and the layers the map allows (a lazy import inside a function counts
too); the modules form no circle; the layers the map marks need no Pinocchio; and nothing outside
``model/`` reaches past the ``Coordinates`` protocol."""
from __future__ import annotations

import ast
import re
import shutil
from dataclasses import dataclass
from pathlib import Path

import pytest

from builders import ROOT

PKG = ROOT / "pcmm"
MAP = ROOT / "docs" / "architecture.md"
#: the coordinate strategies behind the protocol: no module outside model/ imports them
STRATEGIES = {"pcmm.model.tree", "pcmm.model.partitioned"}


@dataclass(frozen=True)
class Layer:
    index: int
    package: str  # "base" and "top" are modules of pcmm/ itself
    may_import: frozenset[str]
    no_pinocchio: bool
    modules: tuple[str, ...] = ()  # the base's modules, named in the map


def package_map(text: str) -> list[Layer]:
    """The layers of the map's table, lowest first."""
    rows = [line for line in text.splitlines() if re.match(r"\|\s*\d+\s*\|", line)]
    out = []
    for row in rows:
        cells = [c.strip() for c in row.strip().strip("|").split("|")]
        index, package, may, no_pin, concept = cells
        allowed = frozenset(re.findall(r"`(\w+)`", may)) if may not in ("—", "everything") else frozenset()
        if may == "everything":
            allowed = frozenset({"*"})
        out.append(Layer(int(index), package.strip("`"), allowed, no_pin == "yes",
                         tuple(m[:-3] for m in re.findall(r"`(\w+\.py)`", concept)) if package == "base" else ()))
    return out


def module_name(root: Path, path: Path) -> str:
    rel = path.relative_to(root).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def imports_of(root: Path, path: Path) -> set[str]:
    """The modules of the package and the third-party top-level names ``path`` imports, anywhere
    in the file (lazy imports included), as dotted names (``pcmm.model.configuration``)."""
    me = module_name(root, path).split(".")
    package = me if path.name == "__init__.py" else me[:-1]
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[:len(package) - node.level + 1]
                target = base + (node.module.split(".") if node.module else [])
                if node.module:
                    out.add(".".join(target))
                for a in node.names:  # from . import x: x may be a module
                    out.add(".".join(target + [a.name]))
            elif node.module:
                out.add(node.module)
                out |= {f"{node.module}.{a.name}" for a in node.names}
        elif isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
    return out


def modules_of(root: Path) -> dict[str, Path]:
    return {module_name(root, p): p for p in sorted((root / "pcmm").rglob("*.py"))}


def layer_of(module: str, layers: list[Layer]) -> Layer | None:
    parts = module.split(".")
    by_package = {lay.package: lay for lay in layers}
    if len(parts) > 2 or (len(parts) == 2 and parts[1] in by_package):
        return by_package.get(parts[1])
    if len(parts) == 1:
        return by_package["top"]  # the package's __init__: its face
    base = by_package["base"]
    return base if parts[1] in base.modules else by_package["top"]


def violations(root: Path) -> list[str]:
    """Every import the package map does not allow, and every module-level circle."""
    layers = package_map((root / "docs" / "architecture.md").read_text(encoding="utf-8"))
    mods = modules_of(root)
    problems = []
    graph: dict[str, set[str]] = {}
    for name, path in mods.items():
        mine = layer_of(name, layers)
        if mine is None:
            problems.append(f"{name}: sits in no layer of docs/architecture.md")
            continue
        targets = imports_of(root, path)
        graph[name] = {t for t in targets if t in mods and t != name}
        for t in sorted(graph[name]):
            theirs = layer_of(t, layers)
            if theirs is None or theirs.package in (mine.package, "base") or "*" in mine.may_import:
                continue
            if theirs.package not in mine.may_import:
                problems.append(f"{name} ({mine.package}) imports {t} ({theirs.package}): not allowed by the map")
        if mine.no_pinocchio and any(t.split(".")[0] == "pinocchio" for t in targets):
            problems.append(f"{name} ({mine.package}) imports pinocchio: its layer must work without it")
        if not name.startswith("pcmm.model") and targets & STRATEGIES:
            problems.append(f"{name} imports {sorted(targets & STRATEGIES)}: outside model/ only the "
                            "Coordinates protocol is used")
    problems += [f"circle: {' -> '.join(c)}" for c in circles(graph)]
    return problems


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import circles among modules (each found once, from its first module in a DFS)."""
    out, state, stack = [], {}, []

    def visit(node):
        state[node] = "open"
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if node.startswith(nxt + ".") or nxt.startswith(node + "."):
                continue  # a package's face and its own modules: Python imports the face first
            if state.get(nxt) == "open":
                out.append(stack[stack.index(nxt):] + [nxt])
            elif nxt not in state:
                visit(nxt)
        stack.pop()
        state[node] = "done"
    for node in sorted(graph):
        if node not in state:
            visit(node)
    return out


def test_the_package_map_is_kept():
    problems = violations(ROOT)
    assert not problems, "\n".join(problems)


def test_the_map_names_every_subpackage():
    layers = {lay.package for lay in package_map(MAP.read_text(encoding="utf-8"))}
    packages = {p.parent.name for p in PKG.glob("*/__init__.py")}
    assert packages <= layers, f"subpackages the map lacks: {sorted(packages - layers)}"
    assert layers - {"base", "top"} <= packages, f"the map names packages that do not exist: {sorted(layers - packages - {'base', 'top'})}"


@pytest.mark.parametrize("plant, expected", [
    # results is below run: an import upward
    ("pcmm/results/summary.py", ("from ..run import loop\n", "imports pcmm.run.loop (run): not allowed")),
    # scene must work without Pinocchio
    ("pcmm/scene/spec.py", ("import pinocchio\n", "imports pinocchio")),
    # a lazy import counts too
    ("pcmm/ode/witness.py", ("def _late():\n    from ..scene import spec\n", "imports pcmm.scene.spec (scene)")),
    # reaching past the Coordinates protocol
    ("pcmm/run/approach.py", ("from ..model import partitioned\n", "outside model/ only the Coordinates protocol")),
    # a circle inside one layer
    ("pcmm/events/contact.py", ("from . import transitions\n", "circle: ")),
])
def test_a_planted_violation_fails(tmp_path, plant, expected):
    """The checker is not vacuous: each kind of violation planted in a copy of the package is found."""
    copy = tmp_path / "tree"
    shutil.copytree(PKG, copy / "pcmm", ignore=shutil.ignore_patterns("*.so", "__pycache__"))
    (copy / "docs").mkdir()
    shutil.copy(MAP, copy / "docs" / "architecture.md")
    assert violations(copy) == []
    path, (line, message) = copy / plant, expected
    path.write_text(path.read_text(encoding="utf-8") + "\n" + line, encoding="utf-8")
    found = violations(copy)
    assert any(message in p for p in found), found


def test_the_run_loop_uses_only_the_coordinates_protocol():
    """Every ``coords.X`` in the run loop is a member of pcmm.model.coordinates.Coordinates."""
    from pcmm.model.coordinates import Coordinates
    members = {n for n in dir(Coordinates) if not n.startswith("_")} | set(Coordinates.__annotations__)
    used = set()
    for path in (PKG / "run").glob("*.py"):
        used |= set(re.findall(r"\bcoords\.(\w+)", path.read_text(encoding="utf-8")))
    assert used and used <= members, f"the run loop reaches past the protocol: {sorted(used - members)}"


def test_both_coordinate_strategies_satisfy_the_protocol(tmp_path):
    import pcmm
    from pcmm.model.coordinates import Coordinates
    from pcmm.model.mechanism import Mechanism
    tree = Mechanism(pcmm.load_scene(ROOT / "examples" / "three_bar.toml"))["config1"].coords
    loop = Mechanism(pcmm.load_scene(ROOT / "examples" / "double_folded.toml"))["config1"].coords
    assert type(tree).__name__ == "TreeCoordinates" and type(loop).__name__ == "PartitionedCoordinates"
    assert isinstance(tree, Coordinates) and isinstance(loop, Coordinates)
    assert tree.guards() == [] and len(loop.guards()) == 1  # the loop's singularity guard
