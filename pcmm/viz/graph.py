"""The working cycle as a graph, as the paper's Fig. 3 draws it: the configurations as nodes and
the transitions as edges, each with its guard and its kind (impact, merge, release, latch) and,
after a run, how many times and when it fired.

:func:`edges` reads the recorded transitions (:func:`pcmm.results.trajectory.record_views`): a
latch is one edge (impact + merge) from its configuration to its target, a release one edge, a
stop an impact loop on its configuration, a merge edge to ``merge_to`` when it has one, and a
release edge back when the merge holds by compression only (``unmerge``).  :func:`fired` assigns
each event record of a run to its edge.  :func:`graph_figure` draws it; every node and edge is one
artist with a ``gid`` (``config:<name>``, ``edge:<i>``), so the figure's own data can be checked.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

KINDS = {"impact": "#d62728", "merge": "#7b3fb5", "latch": "#7b3fb5", "pin": "#1f5fa8", "release": "#1a9a3a"}


@dataclass
class Edge:
    source: str
    target: str
    name: str  # the transition's name
    kind: str  # "impact" | "merge" | "latch" | "pin" | "release"
    guard: str
    times: list = field(default_factory=list)  # when it fired (after a run)

    @property
    def label(self) -> str:
        what = {"latch": "latch (impact + merge)", "merge": "merge", "impact": "impact",
                "pin": "pin (impact, point pinned where it lands)", "release": "release"}.get(self.kind, self.kind)
        guard = "hold tensile" if self.kind == "release" and self.guard.startswith("(") else self.guard
        text = f"{self.name}\n{what}: {guard}"
        if self.times:
            t = self.times
            when = f"t = {t[0]:.4g} s" if len(t) == 1 else f"t = {t[0]:.4g} … {t[-1]:.4g} s"
            text += f"\n×{len(t)}, {when}"
        return text


def edges(views: dict) -> list[Edge]:
    """The transitions of a recorded run (or of ``record_views(scene)``) as the graph's edges."""
    out = []
    for tr in views.get("transitions", []) or []:
        if tr["type"] in ("latch", "pin"):
            out.append(Edge(tr["from"], tr["to"], tr["name"], tr["type"], tr["guard"]))
        elif tr["type"] == "release":
            out.append(Edge(tr["from"], tr["to"], tr["name"], "release", tr["guard"]))
        elif tr["type"] == "stop":
            e = tr.get("restitution")
            out.append(Edge(tr["from"], tr["from"], tr["name"], "impact",
                            tr["guard"] + (f", e = {e:g}" if e is not None else "")))
            if tr.get("merge_to"):
                out.append(Edge(tr["from"], tr["merge_to"], tr["name"], "merge", "rebound < v_acc"))
                if tr.get("unmerge"):
                    out.append(Edge(tr["merge_to"], tr["from"], tr["name"], "release", "(holding force tensile)"))
        else:  # a kind the views do not know: an edge of its own
            out.append(Edge(tr["from"], tr.get("to") or tr["from"], tr["name"], tr["type"], tr["guard"]))
    return out


def edge_of(ev: dict) -> tuple[str, str]:
    """``(transition name, edge kind)`` of an event record."""
    tr = ev.get("transition")
    if tr == "release":
        return ev.get("name", ""), "release"
    if tr in ("latch", "pin"):
        return ev.get("name", ""), tr
    return ev.get("name", ""), ("merge" if ev.get("merge") else "impact")


def fired(graph: list[Edge], events: list[dict], where: str = "the run") -> list[Edge]:
    """``graph`` with each edge's firing times from ``events``; an event no edge explains (a
    transition the scene does not declare, e.g. a release a run's --unmerge added) gets an edge
    of its own from its ``from`` to its ``to``."""
    index = {(e.name, e.kind, e.source, e.target): e for e in graph}
    for ev in events:
        name, kind = edge_of(ev)
        key = (name, kind, ev.get("from"), ev.get("to"))
        if key not in index:
            # e.g. a hold made by an earlier merge, released from a later configuration
            index[key] = Edge(ev.get("from"), ev.get("to"), name, kind,
                              "(holding force tensile)" if kind == "release" else "(not in the scene's transitions)")
            graph.append(index[key])
        index[key].times.append(float(ev["t"]))
    return graph


def configurations(views: dict, graph: list[Edge]) -> list[str]:
    names = list(views.get("configurations", {}))
    for e in graph:
        for n in (e.source, e.target):
            if n not in names:
                names.append(n)
    return names


def _rim(centre, angle: float, r: float) -> tuple[float, float]:
    """The point of a node's ellipse (half-axes 1.2 r, 0.65 r) in direction ``angle``."""
    a, b = 1.2 * r, 0.65 * r
    c, s = math.cos(angle), math.sin(angle)
    t = 1.0 / math.hypot(c / a, s / b)
    return centre[0] + t * c, centre[1] + t * s


@dataclass
class GraphFigure:
    figure: object
    nodes: dict  # {configuration: (x, y)}
    edges: list[Edge]


def graph_figure(views: dict, events: list[dict] | None = None, title: str = "", initial: str | None = None,
                 path: str | Path | None = None) -> GraphFigure:
    """Draw the configurations and transitions (with the run's firings when ``events`` is given)."""
    from matplotlib import patches
    from .canvas import _matplotlib
    Figure = _matplotlib()
    graph = edges(views)
    if events is not None:
        graph = fired(graph, events)
    names = configurations(views, graph)
    n = len(names)
    if n == 1:
        nodes = {names[0]: (0.0, 0.0)}
    elif n == 2:
        nodes = {names[0]: (-1.6, 0.0), names[1]: (1.6, 0.0)}
    else:  # a circle, the initial configuration on top, in the order the run visits them
        nodes = {c: (2.8 * math.sin(2 * math.pi * k / n), 2.2 * math.cos(2 * math.pi * k / n))
                 for k, c in enumerate(names)}
    fig = Figure(figsize=(11.0, 8.5 if n > 2 else 5.0), dpi=110)
    ax = fig.add_axes([0.01, 0.01, 0.98, 0.92])
    ax.set_aspect("equal")
    ax.axis("off")
    r = 0.32
    for c, (x, y) in nodes.items():
        ax.add_patch(patches.Ellipse((x, y), 2.4 * r, 1.3 * r, facecolor="#fff4cc" if c == initial else "white",
                                     edgecolor="k", lw=1.4, zorder=3, gid=f"config:{c}"))
        ax.text(x, y, c, ha="center", va="center", fontsize=9, zorder=4, gid=f"config-label:{c}", parse_math=False)
    pair_count: dict = {}
    loops: dict = {}
    for i, e in enumerate(graph):
        colour = KINDS.get(e.kind, "#333333")
        style = dict(color=colour, lw=1.4 + (0.8 if e.times else 0.0), zorder=2,
                     ls="-" if (e.times or events is None) else ":")
        if e.source == e.target:
            k = loops.get(e.source, 0)
            loops[e.source] = k + 1
            x, y = nodes[e.source]
            ang = math.atan2(y, x) if (x, y) != (0.0, 0.0) else math.pi / 2
            ang += 1.1 * k * (1 if x >= 0 else -1)
            art = patches.FancyArrowPatch(_rim((x, y), ang - 0.45, r), _rim((x, y), ang + 0.45, r),
                                          connectionstyle="arc3,rad=2.0", arrowstyle="-|>", mutation_scale=12,
                                          shrinkA=0, shrinkB=0, gid=f"edge:{i}", **style)
            lx, ly = x + (1.2 * r + 0.75) * math.cos(ang), y + (0.65 * r + 0.55) * math.sin(ang)
        else:
            key = tuple(sorted((e.source, e.target)))
            k = pair_count.get(key, 0)
            pair_count[key] = k + 1
            rad = 0.15 + 0.2 * k
            (x0, y0), (x1, y1) = nodes[e.source], nodes[e.target]
            out_ang = math.atan2(y1 - y0, x1 - x0)
            start = _rim((x0, y0), out_ang + 0.9 * rad * -1, r)  # leave and arrive on the rims, as the arc bends
            end = _rim((x1, y1), out_ang + math.pi + 0.9 * rad, r)
            art = patches.FancyArrowPatch(start, end, connectionstyle=f"arc3,rad={rad}", arrowstyle="-|>",
                                          mutation_scale=14, shrinkA=1, shrinkB=1, gid=f"edge:{i}", **style)
            # the label on the curve (matplotlib's arc3 Bezier), a third of the way from the source,
            # so the two directions of a pair and crossing edges keep their labels apart
            cx, cy = 0.5 * (x0 + x1) + rad * (y1 - y0), 0.5 * (y0 + y1) - rad * (x1 - x0)
            u = 0.32 + 0.2 * k
            lx = (1 - u) ** 2 * x0 + 2 * (1 - u) * u * cx + u ** 2 * x1
            ly = (1 - u) ** 2 * y0 + 2 * (1 - u) * u * cy + u ** 2 * y1
        ax.add_patch(art)
        ax.text(lx, ly, e.label, ha="center", va="center", fontsize=7, color=colour, zorder=5, gid=f"edge-label:{i}", parse_math=False,
                bbox=dict(boxstyle="round,pad=0.2", facecolor="white", edgecolor=colour, lw=0.6, alpha=0.9))
    pts = np.array(list(nodes.values()))
    ax.set_xlim(pts[:, 0].min() - 1.9, pts[:, 0].max() + 1.9)
    ax.set_ylim(pts[:, 1].min() - 1.3, pts[:, 1].max() + 1.3)
    head = title or "configurations and transitions"
    if events is not None:
        head += f" — {len(events)} events"
    fig.suptitle(head, fontsize=11, parse_math=False)
    from matplotlib.lines import Line2D
    fig.legend(handles=[Line2D([], [], color=c, lw=2, label=k) for k, c in KINDS.items() if k != "latch"]
               + [Line2D([], [], color="k", lw=2, ls=":", label="never fired")] * (events is not None),
               loc="lower left", fontsize=8)
    if path is not None:
        fig.savefig(path)
    return GraphFigure(fig, nodes, graph)


def drawn(fig) -> tuple[list[str], list[int]]:
    """The configurations and edges a graph figure draws, read from its artists' gids."""
    gids = [a.get_gid() for a in fig.findobj() if a.get_gid()]
    return ([g[len("config:"):] for g in gids if g.startswith("config:")],
            [int(g[len("edge:"):]) for g in gids if g.startswith("edge:")])
