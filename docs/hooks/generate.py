"""MkDocs hook: the parts of the site that are generated, so that they cannot drift.

* ``index.md`` is the README itself (its links rewritten for the site).
* ``<!-- generated: scene-keys -->`` in a page becomes the scene format's key tables, read from
  the tables the loader validates with (``pcmm.scene.load``'s ``*_KEYS``, and the solver
  settings' registry ``pcmm.scene.settings.SETTINGS``).
* ``<!-- generated: cli -->`` becomes the command-line reference, read from ``pcmm.cli``'s
  argparse parser.
* A link from a page to a file of the repository outside ``docs/`` (a scene, a URDF, a test) is
  served under ``repo/`` so that it resolves on the site as it does on GitHub.
"""
from __future__ import annotations

import argparse
import math
import os
import re
import sys
from pathlib import Path

from mkdocs.structure.files import File

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

#: a markdown link or image target: ](target) or ](target#anchor)
LINK = re.compile(r"(\]\()([^)\s#]+)((?:#[^)\s]*)?\))")
MARKER = re.compile(r"<!--\s*generated:\s*([\w-]+)\s*-->")
REPO = "repo"  # where repository files outside docs/ are served


# ---- links ------------------------------------------------------------------------------------
def _local(target: str) -> bool:
    return not re.match(r"^[a-z][a-z0-9+.-]*:", target) and not target.startswith("/")


def repo_targets(text: str, base: Path, docs: Path) -> set[Path]:
    """The files outside ``docs`` that ``text`` (a file in folder ``base``) links to."""
    out = set()
    for m in LINK.finditer(text):
        target = m.group(2)
        if not _local(target):
            continue
        path = (base / target).resolve()
        if path.is_file() and docs not in path.parents and ROOT in path.parents:
            out.add(path)
    return out


def rewrite_links(text: str, base: Path, here: Path, docs: Path) -> str:
    """Links of ``text`` (written in folder ``base``) rewritten for a page served from folder
    ``here`` of the docs: pages in docs/ by their path, other repository files under repo/."""
    def sub(m):
        target = m.group(2)
        if not _local(target):
            return m.group(0)
        path = (base / target).resolve()
        if not path.exists() or ROOT not in path.parents:
            return m.group(0)  # left for MkDocs to report
        if docs in path.parents or path == docs:
            new = path
        else:
            new = docs / REPO / path.relative_to(ROOT)
        rel = os.path.relpath(new, here).replace(os.sep, "/")
        if path.is_dir() and not rel.endswith("/"):
            rel += "/"
        return m.group(1) + rel + m.group(3)
    return LINK.sub(sub, text)


# ---- the scene format ---------------------------------------------------------------------------
def _check_text(check) -> str:
    """What a schema check allows, in words."""
    if check is None:
        return ""
    from pcmm.scene import schema as S
    named = {S.positive: "> 0", S.non_negative: "≥ 0", S.unit_interval: "in [0, 1]",
             S.numbers_list: "a non-empty list of numbers", S.names_list: "a list of names"}
    if check in named:
        return named[check]
    qual = getattr(check, "__qualname__", "")
    cells = {name: cell.cell_contents for name, cell in
             zip(check.__code__.co_freevars, check.__closure__ or ())}
    if qual.startswith("one_of."):
        return "one of " + ", ".join(f"`{c}`" for c in cells["choices"])
    if qual.startswith("vector."):
        return f"[{cells['n']} numbers]"
    if qual.startswith("vector_or."):
        return f"[{cells['n']} numbers] or " + " or ".join(f'`"{w}"`' for w in cells["words"])
    if qual.startswith("nonzero_vector."):
        return f"[{cells['base'].__closure__[0].cell_contents} numbers], not zero"
    return ""


def _cell(text) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def _kind(kind: str) -> str:
    return " or ".join(kind.split("|"))


def key_table(keys) -> str:
    rows = ["| key | kind | required / default | allowed | meaning |", "|---|---|---|---|---|"]
    for k in keys:
        need = "required" if k.required else ("optional" if k.default is None else f"default `{k.default!r}`")
        rows.append(f"| `{k.name}` | {_kind(k.kind)} | {_cell(need)} | {_cell(_check_text(k.check))} | {_cell(k.doc)} |")
    return "\n".join(rows)


def solver_table() -> str:
    from pcmm.scene.settings import SETTINGS
    rows = ["| key | kind | default | allowed | meaning | `pcmm run` flag |", "|---|---|---|---|---|---|"]
    for s in SETTINGS:
        allowed = ", ".join(f"`{c}`" for c in s.choices()) if s.choices else _check_text(s.check)
        default = "inf" if isinstance(s.default, float) and math.isinf(s.default) else repr(s.default)
        rows.append(f"| `{s.name}` | {s.kind} | `{default}` | {_cell(allowed)} | {_cell(s.help)} | `{s.flag}` |")
    return "\n".join(rows)


def scene_keys() -> str:
    from pcmm.scene import load as L
    tables = [
        ("The file's top level", "", L.TOP_KEYS),
        ("`[scene]`", "", L.SCENE_KEYS),
        ("`[solver]`", "Every key is optional; a `pcmm run` flag (or a `RunOptions` field) of the same "
         "name wins over the scene.", None),
        ("`[configurations.NAME]`", "One table per configuration: `urdf`, or `from` and `lock` (a derived "
         "configuration).", L.CONFIG_KEYS),
        ("`cut_joints` entries", "`{ name, type, a, point_a, b, point_b, ... }` in a configuration's "
         "`cut_joints` list.", L.CUT_JOINT_KEYS),
        ("`[initial]`", "", L.INITIAL_KEYS),
        ("A measure", "`measure` and `branch` tables name one of these; a force's `on` names a `joint` (a "
         "torque or force between the joint's two bodies) or a `link` (a torque on it from the frame), never a "
         "`between`.", L.MEASURE_KEYS),
        ("`[[forces]]`", "", L.FORCE_KEYS),
        ("`[[drives]]`", "", L.DRIVE_KEYS),
        ("`[[transitions]]`", "", L.TRANSITION_KEYS),
        ("A transition's `guard`", "", L.GUARD_KEYS),
        ("A transition's `contact`", "", L.CONTACT_KEYS),
    ]
    out = []
    for title, intro, keys in tables:
        out += [f"### {title}", ""]
        if intro:
            out += [intro, ""]
        out += [solver_table() if keys is None else key_table(keys), ""]
    out += ["Force types and the keys each requires and allows:", "",
            "| `type` | required | allowed |", "|---|---|---|"]
    for name, (need, allow) in L.FORCE_TYPES.items():
        out.append(f"| `{name}` | {', '.join(f'`{k}`' for k in sorted(need)) or '—'} | "
                   f"{', '.join(f'`{k}`' for k in sorted(allow))} |")
    out += ["", "Transition types: " + ", ".join(f"`{t}`" for t in L.TRANSITION_TYPES)
            + "; guard types: " + ", ".join(f"`{t}`" for t in L.GUARD_TYPES)
            + "; cut-joint types (constraint rows): "
            + ", ".join(f"`{t}` ({n})" for t, n in L.CUT_JOINT_TYPES.items()) + ".", ""]
    return "\n".join(out)


# ---- the command line ---------------------------------------------------------------------------
def _flags(action) -> str:
    if action.option_strings:
        names = ", ".join(action.option_strings)
        if action.nargs != 0:
            meta = action.metavar or action.dest.upper()
            names += f" {meta}"
        return f"`{names}`"
    return f"`{action.metavar or action.dest}`" + (" …" if action.nargs in ("+", "*") else "")


def cli_reference() -> str:
    from pcmm.cli import build_parser
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    helps = {c.dest: c.help for c in sub._choices_actions}
    out = []
    for name, p in sub.choices.items():
        p.formatter_class = lambda prog: argparse.HelpFormatter(prog, width=100)  # not the terminal's
        usage = p.format_usage().replace("usage: ", "").strip()
        out += [f"### `pcmm {name}`", "", _cell(helps.get(name, "")), "", "```text", usage, "```", "",
                "| argument | meaning | default |", "|---|---|---|"]
        for a in p._actions:
            if isinstance(a, argparse._HelpAction):
                continue
            default = "" if a.default in (None, False, [], argparse.SUPPRESS) or a.required else f"`{a.default}`"
            text = a.help or ""
            if a.choices and not isinstance(a, argparse._SubParsersAction):
                text += (" " if text else "") + "(" + ", ".join(f"`{c}`" for c in a.choices) + ")"
            if a.required and a.option_strings:
                text = "required; " + text
            out.append(f"| {_flags(a)} | {_cell(text)} | {_cell(default)} |")
        out.append("")
    return "\n".join(out)


GENERATORS = {"scene-keys": scene_keys, "cli": cli_reference}


# ---- MkDocs events ------------------------------------------------------------------------------
def on_files(files, config):
    docs = Path(config["docs_dir"]).resolve()
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    files.append(File.generated(config, "index.md", content=rewrite_links(readme, ROOT, docs, docs)))
    wanted = repo_targets(readme, ROOT, docs)
    for f in list(files):
        if f.src_uri.endswith(".md") and f.abs_src_path:
            src = Path(f.abs_src_path)
            wanted |= repo_targets(src.read_text(encoding="utf-8"), src.parent, docs)
    for path in sorted(wanted):
        uri = f"{REPO}/{path.relative_to(ROOT).as_posix()}"
        if files.get_file_from_path(uri) is None:
            files.append(File.generated(config, uri, abs_src_path=str(path)))
    return files


def on_page_markdown(markdown, page, config, files):
    docs = Path(config["docs_dir"]).resolve()
    if page.file.abs_src_path:  # the README's index is rewritten already
        src = Path(page.file.abs_src_path).resolve()
        markdown = rewrite_links(markdown, src.parent, src.parent, docs)

    def generate(m):
        name = m.group(1)
        if name not in GENERATORS:
            raise ValueError(f"{page.file.src_uri}: unknown generated block {name!r}; known: {sorted(GENERATORS)}")
        return GENERATORS[name]()
    return MARKER.sub(generate, markdown)
