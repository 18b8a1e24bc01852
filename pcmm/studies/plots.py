"""Figures of a design study: each quantity of the results table against each swept value.

With several swept values, the runs that share the other values are joined by one
line (a grid) when there are few such groups, and shown as points otherwise
(random or Latin-hypercube samples).  Runs that stopped early (``partial``) are
drawn hollow; failed runs have no quantities and are left out.
"""
from __future__ import annotations

import csv
import math
import re
from pathlib import Path

from .job import QUANTITIES

_MAX_LINES = 8


def _number(text: str) -> float | None:
    try:
        x = float(text)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text).strip("_")


def plain_text(text: str) -> str:
    """``text`` as matplotlib shows it literally: ``$`` escaped (no mathtext: a scene's name
    or a value path is never parsed as TeX), control characters shown escaped."""
    from ..files import terminal_text
    return terminal_text(str(text)).replace("$", r"\$")


def read_rows(table: str | Path) -> list[dict]:
    """The rows of a results table that have quantities (complete and partial runs)."""
    with open(table, newline="", encoding="utf-8") as f:
        return [r for r in csv.DictReader(f) if r["status"] in ("complete", "partial")]


def numeric_columns(rows: list[dict], paths) -> list[str]:
    """The quantities and collected columns with a number in some row."""
    extra = [c for c in (rows[0] if rows else {}) if c not in ("run", "status", "error", "check", *paths, *QUANTITIES)]
    return [q for q in (*QUANTITIES, *extra) if any(_number(r.get(q)) is not None for r in rows)]


def plot_sweep(table: str | Path, paths, out_dir: str | Path, quantities=None) -> list[Path]:
    """Write ``QUANTITY__vs__PATH.png`` into ``out_dir`` for every numeric quantity
    (default: those of :data:`~pcmm.sweep.QUANTITIES` and the collected columns)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    rows = read_rows(table)
    paths = list(paths)
    if quantities is None:
        quantities = numeric_columns(rows, paths)
    out_dir = Path(out_dir)
    files = []
    for x in paths:
        others = [p for p in paths if p != x]
        groups: dict[tuple, list] = {}
        for r in rows:
            groups.setdefault(tuple(r[p] for p in others), []).append(r)
        as_lines = bool(others) and len(groups) <= _MAX_LINES or not others
        for q in quantities:
            fig, ax = plt.subplots(figsize=(6.4, 4.2))
            for key, grp in sorted(groups.items(), key=lambda kv: tuple(_number(v) or 0 for v in kv[0])):
                pts = sorted((_number(r[x]), _number(r[q]), r["status"]) for r in grp
                             if _number(r[x]) is not None and _number(r[q]) is not None)
                if not pts:
                    continue
                label = plain_text(", ".join(f"{p} = {v}" for p, v in zip(others, key))) or None
                xs, ys = [p[0] for p in pts], [p[1] for p in pts]
                if as_lines:
                    line, = ax.plot(xs, ys, "-", lw=1.2, label=label if len(groups) > 1 else None)
                    color = line.get_color()
                else:
                    color = "C0"
                full = [(a, b) for a, b, s in pts if s == "complete"]
                part = [(a, b) for a, b, s in pts if s != "complete"]
                if full:
                    ax.plot(*zip(*full), "o", ms=4, color=color)
                if part:
                    ax.plot(*zip(*part), "o", ms=5, mfc="none", color=color)
            ax.set_xlabel(plain_text(x))
            ax.set_ylabel(plain_text(q))
            ax.set_title(plain_text(QUANTITIES.get(q, q).split(";")[0]), fontsize=9)
            ax.grid(True, alpha=0.3)
            if as_lines and len(groups) > 1:
                ax.legend(fontsize=7)
            fig.tight_layout()
            path = out_dir / f"{_slug(q)}__vs__{_slug(x)}.png"
            fig.savefig(path, dpi=110)
            plt.close(fig)
            files.append(path)
    return files
