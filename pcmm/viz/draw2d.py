"""The 2D sketch of a recorded run at an instant (matplotlib): the links' bodies and the
engineer's symbols of :mod:`pcmm.viz.sketch`, the event plates, moment arcs and impulse arrows,
the time readout and a legend naming the links.  The video (:mod:`pcmm.viz.video`) draws its
frames with it.  Every drawn symbol carries a ``gid`` (``"<kind>:<name>"``) so a test can find it."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .marks import RecordedRun
from .page import drawn_impacts, impulse_label
from . import sketch as sk

#: Link colours of the sketch (the root link, the frame, is grey).
COLOURS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#bcbd22", "#17becf")
FRAME_GREY = "#808080"
ARROW = "#c00000"
FLASH_S = 0.1  # the impulse arrow's time on screen (the replay page's)


def link_colours(run: RecordedRun) -> dict[str, str]:
    roots = sk.root_links(run)
    out, k = {}, 0
    for link in run.links:
        if link in roots:
            out[link] = FRAME_GREY
        else:
            out[link] = COLOURS[k % len(COLOURS)]
            k += 1
    return out


def _bodies(run: RecordedRun) -> dict[str, dict[str, list]]:
    """``{configuration: {link: [(kind, size, (x, y, yaw))]}}`` of the recorded URDF visuals
    (boxes and spheres; the pins' cylinders are the joints' symbols)."""
    import xml.etree.ElementTree as ET
    out = {}
    for c, v in run.views.get("configurations", {}).items():
        per = {}
        for link in ET.fromstring(v["urdf"]).findall("link"):
            items = []
            for vis in link.findall("visual"):
                g = vis.find("geometry")
                shape = g[0] if g is not None and len(g) else None
                o = vis.find("origin")
                xyz = sk._floats(o.get("xyz") if o is not None else None, 3, (0.0, 0.0, 0.0))
                rpy = sk._floats(o.get("rpy") if o is not None else None, 3, (0.0, 0.0, 0.0))
                if shape is None:
                    continue
                if shape.tag == "box":
                    size = sk._floats(shape.get("size"), 3, None)
                    if size and abs(rpy[0]) < 1e-9 and abs(rpy[1]) < 1e-9:
                        items.append(("box", size[:2], (xyz[0], xyz[1], rpy[2])))
                elif shape.tag == "sphere":
                    items.append(("sphere", (float(shape.get("radius")),), (xyz[0], xyz[1], 0.0)))
            per[link.get("name")] = items
        out[c] = per
    return out


class Sketch:
    """A run's drawing, ready to be drawn at any instant (the symbols are worked out once)."""

    def __init__(self, run: RecordedRun, colour: str | None = None, ghost: bool = False):
        self.run = run
        self.symbols = sk.symbols(run)
        self.marks = sk.event_marks(run)
        self.size = sk.scale(run)
        self.bodies = _bodies(run)
        self.colours = {k: (colour if colour and v != FRAME_GREY else v) for k, v in link_colours(run).items()}
        self.ghost = ghost
        self.impacts = drawn_impacts(run)
        p_max = max([abs(float(e["impulse"]["normal"])) for e in self.impacts] + [0.0])
        self.arrow_scale = 6 * self.size / p_max if p_max > 0 else 0.0

    def extent(self, times) -> tuple[float, float, float, float]:
        """(xmin, xmax, ymin, ymax) of the links' frames and symbols over ``times``, with room for the symbols."""
        pts = []
        for t in times:
            pts += [p.xy for p in sk.world(self.run, self.symbols, t)]
            for link in self.run.links:
                pose = sk.pose_at(self.run, link, t)
                if pose is None:
                    continue
                for c in self.bodies.values():
                    for kind, size, (x, y, yaw) in c.get(link, []):
                        r = 0.5 * math.hypot(*size) if kind == "box" else size[0]
                        cx, cy = sk.to_world(pose, (x, y))
                        pts += [(cx - r, cy - r), (cx + r, cy + r)]
        pts = np.array(pts) if pts else np.zeros((1, 2))
        m = 2.5 * self.size
        return (float(pts[:, 0].min() - m), float(pts[:, 0].max() + m),
                float(pts[:, 1].min() - m), float(pts[:, 1].max() + m))

    # -- drawing
    def draw(self, ax, t: float) -> list:
        """Draw the run at ``t`` into ``ax``; returns the artists."""
        from matplotlib import patches
        run, s = self.run, self.size
        conf = sk.configuration_at(run, t)
        artists = []
        alpha = 0.35 if self.ghost else 1.0
        ls = "--" if self.ghost else "-"
        for link in run.links:
            pose = sk.pose_at(run, link, t)
            if pose is None:
                continue
            for kind, size, (x, y, yaw) in self.bodies.get(conf, {}).get(link, []):
                cx, cy = sk.to_world(pose, (x, y))
                if kind == "box":
                    w, h = size
                    ang = pose[2] + yaw
                    c, sn = math.cos(ang), math.sin(ang)
                    corner = (cx - 0.5 * (w * c - h * sn), cy - 0.5 * (w * sn + h * c))
                    p = patches.Rectangle(corner, w, h, angle=math.degrees(ang), rotation_point="xy",
                                          facecolor=self.colours.get(link, FRAME_GREY), edgecolor="k",
                                          lw=0.8, ls=ls, alpha=alpha, zorder=2, gid=f"body:{link}")
                else:
                    p = patches.Circle((cx, cy), size[0], facecolor=self.colours.get(link, FRAME_GREY),
                                       edgecolor="k", lw=0.8, ls=ls, alpha=alpha, zorder=2, gid=f"body:{link}")
                ax.add_patch(p)
                artists.append(p)
        for pl in sk.world(run, self.symbols, t):
            artists += _symbol(ax, pl, s, alpha)
        if not self.ghost:
            for pl in sk.world(run, self.marks, t):
                artists += _mark(ax, pl, s)
            for ev in self.impacts:
                te = float(ev["t"])
                if te <= t < te + FLASH_S and self.arrow_scale > 0:
                    x, y = ev["contact_point"][:2]
                    vx, vy = (self.arrow_scale * float(c) for c in ev["impulse"]["vector"][:2])
                    a = patches.FancyArrow(x, y, vx, vy, width=0.25 * s, head_width=0.8 * s,
                                           head_length=0.8 * s, length_includes_head=True, color=ARROW,
                                           zorder=8, gid=f"impulse:{ev.get('name', '')}")
                    ax.add_patch(a)
                    artists.append(a)
                    artists.append(ax.text(x + vx, y + vy, " " + impulse_label(ev), color=ARROW, fontsize=7,
                                           zorder=9, gid="impulse-label"))
        return artists

    def legend_handles(self):
        from matplotlib.patches import Patch
        return [Patch(facecolor=c, edgecolor="k", label=link) for link, c in self.colours.items()]


def _symbol(ax, pl: sk.Placed, s: float, alpha: float) -> list:
    from matplotlib import patches
    sym = pl.symbol
    x, y = pl.xy
    gid = f"{sym.kind}:{sym.name}"
    out = []
    if sym.kind == "ground":
        w = 2.4 * s
        base = y - 1.2 * s
        out.append(ax.plot([x - w / 2, x + w / 2], [base, base], color="k", lw=1.2, alpha=alpha, zorder=3, gid=gid)[0])
        for k in range(7):
            hx = x - w / 2 + k * w / 6
            out.append(ax.plot([hx, hx - 0.4 * s], [base, base - 0.4 * s], color="k", lw=0.8, alpha=alpha,
                               zorder=3, gid=gid + ":hatch")[0])
    elif sym.kind == "pivot":
        tri = patches.Polygon([(x, y), (x - 0.7 * s, y - 1.2 * s), (x + 0.7 * s, y - 1.2 * s)], closed=True,
                              facecolor="white", edgecolor="k", lw=1.0, alpha=alpha, zorder=4, gid=gid)
        ax.add_patch(tri)
        out.append(tri)
        c = patches.Circle((x, y), 0.35 * s, facecolor="white", edgecolor="k", lw=1.0, alpha=alpha, zorder=6,
                           gid=gid + ":pin")
        ax.add_patch(c)
        out.append(c)
    elif sym.kind == "revolute":
        c = patches.Circle((x, y), 0.35 * s, facecolor="white", edgecolor="k", lw=1.2, alpha=alpha, zorder=6, gid=gid)
        ax.add_patch(c)
        out.append(c)
    elif sym.kind == "locked":
        if sym.shape == "square":
            p = patches.Rectangle((x - 0.5 * s, y - 0.5 * s), s, s, facecolor="k", edgecolor="k", alpha=alpha,
                                  zorder=7, gid=gid)
        else:
            p = patches.Circle((x, y), 0.45 * s, facecolor="k", edgecolor="k", alpha=alpha, zorder=7, gid=gid)
        ax.add_patch(p)
        out.append(p)
    elif sym.kind == "slider":
        c, sn = math.cos(pl.angle), math.sin(pl.angle)
        w, h = 1.6 * s, 0.9 * s
        corner = (x - 0.5 * (w * c - h * sn), y - 0.5 * (w * sn + h * c))
        p = patches.Rectangle(corner, w, h, angle=math.degrees(pl.angle), rotation_point="xy", facecolor="white",
                              edgecolor="k", lw=1.2, alpha=alpha, zorder=6, gid=gid)
        ax.add_patch(p)
        out.append(p)
    elif sym.kind == "guide":
        c, sn = math.cos(pl.angle), math.sin(pl.angle)
        L = 12 * s
        for off in (-0.6 * s, 0.6 * s):
            ox, oy = -sn * off, c * off
            out.append(ax.plot([x + ox - 0.1 * L * c, x + ox + L * c], [y + oy - 0.1 * L * sn, y + oy + L * sn],
                               color="k", lw=0.9, alpha=alpha, zorder=3, gid=gid)[0])
    elif sym.kind == "cut":
        c = patches.Circle((x, y), 0.4 * s, facecolor="white", edgecolor="#7b3fb5", lw=1.4, alpha=alpha, zorder=6,
                           gid=gid)
        ax.add_patch(c)
        out.append(c)
        out.append(ax.plot([x - 0.6 * s, x + 0.6 * s], [y - 0.6 * s, y + 0.6 * s], color="#7b3fb5", lw=1.4,
                           alpha=alpha, zorder=7, gid=gid + ":slash")[0])
    elif sym.kind == "stop":
        c, sn = math.cos(pl.angle), math.sin(pl.angle)
        if sym.shape == "joint":  # a pin line from the joint along the stop's direction
            out.append(ax.plot([x + 0.5 * s * c, x + 1.6 * s * c], [y + 0.5 * s * sn, y + 1.6 * s * sn],
                               color="#444444", lw=2.5, alpha=alpha, zorder=5, gid=gid, solid_capstyle="butt")[0])
        else:  # a block behind the contact point, its face across the normal
            w, h = 0.5 * s, 1.6 * s
            cx, cy = x - 0.5 * w * c, y - 0.5 * w * sn
            corner = (cx - 0.5 * (w * c - h * sn), cy - 0.5 * (w * sn + h * c))
            p = patches.Rectangle(corner, w, h, angle=math.degrees(pl.angle), rotation_point="xy",
                                  facecolor="#444444", edgecolor="k", alpha=alpha, zorder=5, gid=gid, hatch="///")
            ax.add_patch(p)
            out.append(p)
    return out


def _mark(ax, pl: sk.Placed, s: float) -> list:
    from matplotlib import patches
    sym = pl.symbol
    x, y = pl.xy
    if sym.kind == "plate":
        colour = {"impact": "#d62728", "merge": "#7b3fb5", "release": "#1a9a3a"}.get(sym.extra.get("kind"), "#333333")
        t = ax.text(x + 0.8 * s, y + 0.8 * s, sym.text, fontsize=8, color=colour, parse_math=False, alpha=pl.alpha, zorder=10,
                    gid=f"plate:{sym.name}",
                    bbox=dict(boxstyle="round,pad=0.25", facecolor="white", edgecolor=colour, alpha=pl.alpha))
        return [t]
    if sym.kind == "arc":
        r = 1.3 * s
        sense = 1 if sym.shape == "+" else -1
        a0 = 30.0
        arc = patches.Arc((x, y), 2 * r, 2 * r, theta1=a0, theta2=a0 + 270, color="#c00000", lw=2.0, zorder=9,
                          gid=f"arc:{sym.name}")
        ax.add_patch(arc)
        end = math.radians(a0 + 270 if sense > 0 else a0)
        ex, ey = x + r * math.cos(end), y + r * math.sin(end)
        tx, ty = -math.sin(end) * sense, math.cos(end) * sense  # the tangent, in the moment's sense
        head = patches.FancyArrow(ex - 0.3 * s * tx, ey - 0.3 * s * ty, 0.3 * s * tx, 0.3 * s * ty,
                                  width=0.05 * s, head_width=0.6 * s, head_length=0.5 * s, color="#c00000", zorder=9,
                                  gid=f"arc:{sym.name}:head")
        ax.add_patch(head)
        lab = ax.text(x + 1.1 * r, y - 1.1 * r, sym.text, fontsize=7, color="#c00000", parse_math=False, zorder=10,
                      gid=f"arc-label:{sym.name}")
        return [arc, head, lab]
    return []


def draw_frame(fig, sketches: list[Sketch], t: float, box, title: str = "", names=()) -> dict:
    """Draw one frame (every sketch at ``t``, the first on top of the ghosts) into ``fig``: the
    mechanism's axes fixed to ``box`` (xmin, xmax, ymin, ymax), the time readout and a legend."""
    ax = fig.add_axes([0.02, 0.1, 0.74, 0.84])
    ax.set_aspect("equal")
    ax.set_xlim(box[0], box[1])
    ax.set_ylim(box[2], box[3])
    ax.set_xticks([])
    ax.set_yticks([])
    artists = []
    for sk_ in sketches[::-1]:
        artists += sk_.draw(ax, t)
    fig.text(0.02, 0.03, f"t = {t:.4f} s", fontsize=11, family="monospace", gid="readout", parse_math=False)
    for i, sk_ in enumerate(sketches):
        conf = sk.configuration_at(sk_.run, t)
        name = names[i] if i < len(names) else sk_.run.scene_name
        fig.text(0.78, 0.92 - 0.05 * i, f"{name}: {conf}", fontsize=8, gid=f"readout:{i}", parse_math=False)
    handles = sketches[0].legend_handles()
    fig.legend(handles=handles, loc="lower right", fontsize=8, title="links", frameon=True)
    if title:
        ax.set_title(title, fontsize=10, parse_math=False)
    return {"ax": ax, "artists": artists}


def sketch_figure(run: RecordedRun, t: float, path: str | Path | None = None, others=(), size=(8.0, 5.0), dpi=110,
                  box=None):
    """The sketch of ``run`` (and ``others``, dashed ghosts) at ``t``: a matplotlib Figure,
    written to ``path`` when given; ``box`` (xmin, xmax, ymin, ymax) narrows the view to part of
    the scene (a rimless wheel on a long slope), else it holds everything the run sweeps."""
    from .canvas import _matplotlib
    Figure = _matplotlib()
    fig = Figure(figsize=size, dpi=dpi)
    sketches = [Sketch(run)] + [Sketch(o, colour="#888888", ghost=True) for o in others]
    times = np.linspace(float(run.segments[0].t[0]), float(run.segments[-1].t[-1]), 40)
    box = box if box is not None else _union([s.extent(times) for s in sketches])
    names = [r.scene_name + ("" if r.impact else " (without impact, dashed)") for r in [run, *others]]
    draw_frame(fig, sketches, t, box, title=f"{run.scene_name} at t = {t:.4g} s", names=names)
    if path is not None:
        fig.savefig(path)
    return fig


def _union(boxes):
    return (min(b[0] for b in boxes), max(b[1] for b in boxes), min(b[2] for b in boxes), max(b[3] for b in boxes))
