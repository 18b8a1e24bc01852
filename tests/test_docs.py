"""The documentation keeps its promises: the site builds without a warning (``mkdocs build
--strict``), every ``python`` and ``sh`` block of the README and of docs/ runs as written (a
``text`` block right after a ``python`` block is its printed output, compared line by line), every
relative link resolves, the README stays a front page (at most 200 lines) whose second command is
the one CI runs, and the generated references name every scene key, solver setting and flag.

A block that must not run says so, with its reason, on the line before its fence:
``<!-- not run: rewrites the shipped figures -->``.  docs/tutorial.md's blocks are run by
tests/test_tutorial.py, in order, as one session."""
from __future__ import annotations

import importlib.util
import os
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from builders import ROOT

DOCS = ROOT / "docs"
README = ROOT / "README.md"
#: pages whose blocks another test runs, or that hold no runnable blocks by design
RUN_ELSEWHERE = {DOCS / "tutorial.md": "tests/test_tutorial.py"}
FENCE = re.compile(r"^```(\w*)[^\n]*\n(.*?)^```[ \t]*$", re.S | re.M)
NOT_RUN = re.compile(r"<!--\s*not run:\s*(.*?)\s*-->\s*$")
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")


def pages() -> list[Path]:
    return [README] + sorted(p for p in DOCS.rglob("*.md") if "hooks" not in p.parts)


@dataclass(frozen=True)
class Block:
    page: Path
    line: int
    lang: str
    body: str
    output: str | None  # the text block that follows a python block
    skip: str | None  # the reason it is not run

    @property
    def id(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}"


def blocks_of(page: Path) -> list[Block]:
    text = page.read_text(encoding="utf-8")
    found = list(FENCE.finditer(text))
    out = []
    for i, m in enumerate(found):
        lang = m.group(1)
        if lang not in ("python", "sh"):
            continue
        line = text.count("\n", 0, m.start()) + 1
        before = text[:m.start()].rstrip("\n").rsplit("\n", 1)[-1]
        skip = NOT_RUN.search(before)
        output = None
        if lang == "python" and i + 1 < len(found) and found[i + 1].group(1) == "text":
            between = text[m.end():found[i + 1].start()]
            if len(between.strip().splitlines()) <= 1:  # at most a word such as "prints"
                output = found[i + 1].group(2)
        out.append(Block(page, line, lang, m.group(2), output, skip.group(1) if skip else None))
    return out


def runnable() -> list[Block]:
    out = []
    for page in pages():
        if page in RUN_ELSEWHERE:
            continue
        blocks = blocks_of(page)
        if page == README:
            blocks = blocks[1:]  # the two set-up commands: see test_the_readme_commands_are_what_ci_runs
        out += blocks
    return out


def _workspace(tmp_path: Path) -> dict:
    """A fresh folder that sees the repository's examples, URDFs, tests and benchmarks where a
    reader's clone has them, and an environment whose ``pcmm`` and ``python`` are this
    checkout's, with tests/ importable as in the suite (its builders and references)."""
    for name in ("examples", "urdf", "tests", "benchmarks"):
        (tmp_path / name).symlink_to(ROOT / name)
    path = [str(ROOT), str(ROOT / "tests"), os.environ.get("PYTHONPATH", "")]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in path if p),
               MPLBACKEND="Agg")
    env.pop("DISPLAY", None)
    return env


@pytest.mark.parametrize("block", runnable(), ids=lambda b: b.id)
def test_every_code_block_runs(block: Block, tmp_path):
    if block.skip is not None:
        assert len(block.skip) >= 10, f"{block.id}: a block that is not run says why"
        pytest.skip(f"not run: {block.skip}")
    env = _workspace(tmp_path)
    if block.lang == "python":
        script = tmp_path / "block.py"
        script.write_text(block.body, encoding="utf-8")
        cmd = [sys.executable, str(script)]
    else:
        prelude = (f'pcmm() {{ {shlex.quote(sys.executable)} -m pcmm.cli "$@"; }}\n'
                   f'python() {{ {shlex.quote(sys.executable)} "$@"; }}\nset -e\n')
        cmd = ["bash", "-c", prelude + block.body]
    done = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, f"{block.id} failed ({done.returncode}):\n{done.stdout}\n{done.stderr}"
    if block.output is not None:
        assert done.stdout.strip().splitlines() == block.output.strip().splitlines(), \
            f"{block.id}: the output printed under the block is not what it prints:\n{done.stdout}"


def test_the_readme_shows_what_its_python_prints():
    """The ten lines of Python come with their output, checked by the test above."""
    python = [b for b in blocks_of(README) if b.lang == "python"]
    assert python and python[0].output is not None and python[0].skip is None
    assert len([line for line in python[0].body.splitlines() if line.strip()]) <= 12


def test_the_readme_is_a_front_page():
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 200, f"README.md has {len(lines)} lines; the front page keeps to 200"
    text = "\n".join(lines)
    for page in ("docs/tutorial.md", "docs/architecture.md", "docs/api.md", "docs/scene_format.md",
                 "docs/cli.md", "docs/limits.md", "docs/performance.md"):
        assert f"]({page})" in text, f"the README's documentation table lacks {page}"
    assert "pcmm new" in text and "10.1155/2020/8837838" in text
    assert re.search(r"!\[[^\]]+\]\(docs/figures/[^)]+\.png\)", text), "the front page shows one figure"


def test_the_readme_commands_are_what_ci_runs():
    first = blocks_of(README)[0]
    assert first.lang == "sh" and README.read_text(encoding="utf-8").splitlines()[2] == "```sh"
    commands = first.body.strip().splitlines()
    assert len(commands) == 2, "the README starts with exactly two commands"
    assert "pcmm run examples/" in commands[0]
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8").splitlines()
    assert commands[1] in ci, f".ci/run does not run the README's second command {commands[1]!r}"


@pytest.mark.parametrize("page", pages(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_link_resolves(page: Path):
    text = FENCE.sub("", page.read_text(encoding="utf-8"))
    text = re.sub(r"`[^`\n]*`", "", text)  # code spans are not links
    broken = []
    for target in LINK.findall(text):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target) or target.startswith("#"):
            continue
        path = (page.parent / target.split("#")[0]).resolve()
        if not path.exists():
            broken.append(target)
    assert not broken, f"{page.relative_to(ROOT)}: links to nothing: {broken}"


def _hook():
    pytest.importorskip("mkdocs")
    spec = importlib.util.spec_from_file_location("pcmm_docs_hook", DOCS / "hooks" / "generate.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_scene_reference_names_every_key():
    from pcmm.scene import load as L
    from pcmm.scene.settings import SETTINGS
    text = _hook().scene_keys()
    for keys in (L.TOP_KEYS, L.SCENE_KEYS, L.CONFIG_KEYS, L.CUT_JOINT_KEYS, L.INITIAL_KEYS, L.MEASURE_KEYS,
                 L.FORCE_KEYS, L.DRIVE_KEYS, L.TRANSITION_KEYS, L.GUARD_KEYS, L.CONTACT_KEYS):
        for key in keys:
            assert f"| `{key.name}` |" in text
    for s in SETTINGS:
        assert f"| `{s.name}` |" in text and f"`{s.flag}`" in text
    # a check is described in words: restitution's interval, a force's type choices
    assert "in [0, 1]" in text and "`point_spring`" in text


def test_every_scene_key_says_what_it_means():
    """A new user reading the generated tables met 39 keys with an empty "meaning" cell (a
    transition's from, to, merge_to, restitution, a guard's direction, a contact's points, ...):
    every key of every table the loader validates with carries its doc, and each row of the
    generated reference ends with a non-empty meaning."""
    from pcmm.scene import load as L
    tables = {name: getattr(L, name) for name in dir(L) if name.endswith("_KEYS")}
    assert len(tables) >= 12
    silent = [f"{table}.{key.name}" for table, keys in tables.items() for key in keys if not key.doc.strip()]
    assert not silent, f"keys without a doc: {silent}"
    rows = [line for line in _hook().scene_keys().splitlines()
            if line.startswith("| `") and line.count("|") == 6]
    assert rows and all(line.rsplit("|", 2)[1].strip() for line in rows)


def test_the_cli_reference_names_every_flag():
    import argparse
    from pcmm.cli import build_parser
    text = _hook().cli_reference()
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    for name, parser in sub.choices.items():
        assert f"### `pcmm {name}`" in text
        for action in parser._actions:
            for flag in action.option_strings:
                if flag not in ("-h", "--help"):
                    assert flag in text, f"pcmm {name} {flag} is missing from the CLI reference"


@pytest.mark.slow
def test_the_site_builds_without_a_warning(tmp_path):
    pytest.importorskip("mkdocs")
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(ROOT / "mkdocs.yml"),
                           "-d", str(tmp_path / "site")], cwd=ROOT, capture_output=True, text=True, timeout=600,
                          env=dict(os.environ, NO_MKDOCS_2_WARNING="1"))
    assert done.returncode == 0, f"mkdocs build --strict failed:\n{done.stderr[-4000:]}"
    site = tmp_path / "site"
    assert (site / "index.html").is_file() and (site / "api" / "index.html").is_file()
    # the generated references are in the site, and the API reference came from the docstrings
    assert "--accumulation-speed" in (site / "cli" / "index.html").read_text(encoding="utf-8")
    assert "initial_configuration" in (site / "scene_format" / "index.html").read_text(encoding="utf-8")
    assert "load_scene" in (site / "api" / "index.html").read_text(encoding="utf-8")
