"""Draw docs/figures/conventions.png: pcmm's sign conventions for the tutorial.

(a) contact points and the normal from link a to link b, the relative angle ``between = [A, B]``;
(b) a link torque (from the frame) against a joint torque (equal and opposite on the two bodies);
(c) a closed loop: the URDF spanning tree and the scene's cut joint.

Run: python docs/figures/conventions.py  (writes the PNG next to this file)
"""
from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.patches import Arc, FancyArrowPatch  # noqa: E402

OUT = Path(__file__).with_name("conventions.png")
A_COL, B_COL, F_COL = "#0072bd", "#d95319", "#444444"


def bar(ax, p, q, color, label=None, style="-"):
    ax.plot([p[0], q[0]], [p[1], q[1]], style, color=color, lw=5, solid_capstyle="round", zorder=2)
    if label:
        ax.text((p[0] + q[0]) / 2, (p[1] + q[1]) / 2 + 0.06, label, color=color, ha="center", fontsize=10)


def pin(ax, p, color="k"):
    ax.plot(*p, "o", ms=9, mfc="white", mec=color, mew=2, zorder=4)


def arrow(ax, p, d, color, text=None, off=(0.03, 0.03)):
    ax.add_patch(FancyArrowPatch(p, (p[0] + d[0], p[1] + d[1]), arrowstyle="-|>", mutation_scale=14,
                                 color=color, lw=1.8, zorder=5))
    if text:
        ax.text(p[0] + d[0] + off[0], p[1] + d[1] + off[1], text, color=color, fontsize=10)


def ground(ax, p, w=0.18):
    ax.plot([p[0] - w / 2, p[0] + w / 2], [p[1] - 0.035] * 2, color="k", lw=1.5)
    for k in range(6):
        x = p[0] - w / 2 + k * w / 5
        ax.plot([x, x - 0.03], [p[1] - 0.035, p[1] - 0.07], color="k", lw=1)


def turn(ax, c, r, a0, a1, color, text, where):
    ax.add_patch(Arc(c, 2 * r, 2 * r, theta1=min(a0, a1), theta2=max(a0, a1), color=color, lw=1.6))
    end = math.radians(a1)
    tip = (c[0] + r * math.cos(end), c[1] + r * math.sin(end))
    tang = (-math.sin(end), math.cos(end)) if a1 > a0 else (math.sin(end), -math.cos(end))
    ax.add_patch(FancyArrowPatch(tip, (tip[0] + 0.02 * tang[0], tip[1] + 0.02 * tang[1]), arrowstyle="-|>",
                                 mutation_scale=12, color=color, lw=1.6))
    ax.text(*where, text, color=color, fontsize=10)


def panel_contact(ax):
    o = (0.0, 0.0)
    j = (0.6, 0.0)
    alpha = math.radians(35)
    tip = (j[0] + 0.45 * math.cos(alpha), j[1] + 0.45 * math.sin(alpha))
    ground(ax, o)
    bar(ax, o, j, A_COL, "link a (A)")
    bar(ax, j, tip, B_COL)
    ax.text(tip[0] - 0.05, tip[1] + 0.05, "link b (B)", color=B_COL, fontsize=10)
    pin(ax, o)
    pin(ax, j)
    r = 0.28
    pb = (j[0] + r * math.cos(alpha), j[1] + r * math.sin(alpha))
    ax.plot(*pb, "o", color="k", ms=6, zorder=6)
    ax.text(pb[0] + 0.03, pb[1] - 0.08, "point_a = point_b\n(each in its own link frame)", fontsize=8.5)
    n = (math.sin(alpha), -math.cos(alpha))  # from a towards b: against b's arrival
    arrow(ax, pb, (-0.22 * n[0], -0.22 * n[1]), "#7e2f8e", "b arrives", off=(-0.2, 0.03))
    arrow(ax, pb, (0.22 * n[0], 0.22 * n[1]), "k", "normal n: in a's frame,\nfrom a towards b", off=(0.03, -0.1))
    turn(ax, j, 0.16, 0, 35, "#77ac30", "between = [A, B]\n= θB − θA", (j[0] - 0.3, j[1] - 0.3))
    ax.set_title("(a) contact and relative angle", fontsize=11)


def panel_torques(ax):
    o = (0.0, 0.0)
    j = (0.55, 0.15)
    tip = (1.0, 0.0)
    ground(ax, o)
    bar(ax, o, j, A_COL, "link 1")
    bar(ax, j, tip, B_COL, "link 2")
    pin(ax, o)
    pin(ax, j)
    turn(ax, (0.78, 0.075), 0.1, 200, 340, "k", "on = { link = \"link 2\" }:\ntorque on link 2 from the frame",
         (0.45, -0.38))
    turn(ax, j, 0.13, 20, 150, B_COL, "+τ on link 2", (j[0] + 0.12, j[1] + 0.27))
    turn(ax, j, 0.2, 150, 20, A_COL, "", (0, 0))
    ax.text(j[0] - 0.5, j[1] + 0.27, "−τ on link 1", color=A_COL, fontsize=10)
    ax.text(-0.05, 0.66, "on = { joint = \"J2\" }: equal and opposite", fontsize=10)
    ax.set_title("(b) link torque vs joint torque", fontsize=11)


def panel_cut(ax):
    a, d = (0.0, 0.0), (0.8, 0.0)
    b = (0.1, 0.35)
    c = (0.75, 0.45)
    ground(ax, a)
    ground(ax, d)
    bar(ax, a, b, A_COL, "crank")
    bar(ax, b, c, A_COL, "coupler")
    bar(ax, c, d, B_COL, "rocker", style="-")
    for p in (a, b, c):
        pin(ax, p)
    ax.plot(*d, "o", ms=16, mfc="none", mec="#a2142f", mew=2, ls="none", zorder=6)
    ax.plot(*d, "o", ms=9, mfc="white", mec="#a2142f", mew=2, zorder=5)
    ax.annotate("cut joint (scene):\npoint_a on the frame,\npoint_b on the rocker",
                xy=d, xytext=(0.25, -0.4), fontsize=9, color="#a2142f",
                arrowprops=dict(arrowstyle="->", color="#a2142f"))
    ax.text(-0.05, 0.7, "URDF: the spanning tree frame–crank–coupler–rocker", fontsize=9.5)
    ax.set_title("(c) a closed loop: tree + cut joint", fontsize=11)


def main():
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.6))
    for ax, draw in zip(axes, (panel_contact, panel_torques, panel_cut)):
        draw(ax)
        ax.set_aspect("equal")
        ax.set_xlim(-0.25, 1.25)
        ax.set_ylim(-0.5, 0.85)
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(OUT, dpi=110)
    return OUT


if __name__ == "__main__":
    print(main())
