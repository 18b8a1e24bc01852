"""Draw the pictures of docs/views.md into this folder (PNG).

Runs Example 1 (three_bar, 1 s), Example 2 (double_folded, 3.4 s) and Example 4 (three_bar_cycle,
2.3 s), then draws: the 2D sketch of each at telling instants, the working-cycle graphs (Example 4
with its run's firings), one video frame, and the replay page in headless Chromium (when
/usr/bin/chromium exists).

The example pages (docs/example1.md … docs/point_impacts.md) show each example's drawing and its
`pcmm graph` figure; :func:`example_pages` draws the ones not drawn above: Example 2's graph with its
run's firings, Example 3 (Andrews' mechanism), the rimless wheel (its pinned foot, drawn and in the
replay page) and the compass gait.

Run: python docs/figures/views/make.py          (everything, a few minutes)
     python docs/figures/views/make.py pages    (the example pages' pictures only)
"""
from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pcmm
from pcmm.results.trajectory import record_views
from pcmm.viz.draw2d import sketch_figure
from pcmm.viz.graph import graph_figure
from pcmm.viz.replay import write_html
from pcmm.viz.sketch import pose_at

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[2]


def run(name: str, t_end: float, impact: bool = True):
    scene = pcmm.load_scene(ROOT / "examples" / f"{name}.toml")
    return scene, pcmm.simulate(scene, pcmm.RunOptions(t_end=t_end, impact=impact))


def chromium_shot(html: Path, t: float, out: Path, size="1100,650") -> None:
    exe = shutil.which("chromium")
    if exe is None:
        print("no chromium: replay screenshots skipped")
        return
    with tempfile.TemporaryDirectory() as profile:
        subprocess.run([exe, "--headless", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                        "--disable-gpu-sandbox", "--no-first-run", f"--user-data-dir={profile}",
                        f"--window-size={size}", "--hide-scrollbars", "--virtual-time-budget=3000",
                        f"--screenshot={out}", f"{html.as_uri()}#t={t!r}"], capture_output=True, timeout=180)
    print(out)


def drawing_and_graph(name: str, t_end: float, t: float, scene_and_run=None, around=None) -> None:
    """``sketch_<name>.png`` at ``t`` (``around`` = (link, half-width, half-height, dy): the view
    centred dy below that link's frame at ``t``) and ``graph_<name>.png`` with the run's firings."""
    scene, ex = scene_and_run or run(name, t_end)
    box = None
    if around is not None:
        link, hw, hh, dy = around
        x, y, _ = pose_at(ex, link, t)
        y -= dy
        box = (x - hw, x + hw, y - hh, y + hh)
    sketch_figure(ex, t, HERE / f"sketch_{name}.png", box=box)
    graph_figure(ex.views, ex.events, title=scene.name, initial=scene.initial_configuration,
                 path=HERE / f"graph_{name}.png")
    print(HERE / f"sketch_{name}.png", HERE / f"graph_{name}.png")


def example_pages() -> None:
    """The pictures of the example pages that the views page does not already draw."""
    s2, ex2 = run("double_folded", 3.4)
    graph_figure(ex2.views, ex2.events, title=s2.name, initial=s2.initial_configuration,
                 path=HERE / "graph_example2.png")
    drawing_and_graph("andrews", 0.03, 0.015)
    wheel = run("rimless_wheel", 4.0)  # four strikes; the third foot's stay at 2.2 s
    strikes = [e["t"] for e in wheel[1].events if e["transition"] == "pin"]
    drawing_and_graph("rimless_wheel", 4.0, 0.5 * (strikes[1] + strikes[2]), wheel, around=("wheel", 2.2, 1.4, 0.0))
    gait = run("compass_gait", 2.0)  # two heel strikes; mid-stance of the second step
    steps = [e["t"] for e in gait[1].events if e["transition"] == "pin"]
    drawing_and_graph("compass_gait", 2.0, 0.5 * (steps[0] + steps[1]), gait, around=("leg_a", 1.0, 0.75, 0.5))
    with tempfile.TemporaryDirectory() as tmp:
        page = Path(tmp) / "wheel.html"
        write_html(wheel[1], page, fps=30, view="follow")
        chromium_shot(page, 0.5 * (strikes[1] + strikes[2]), HERE / "replay_rimless_wheel.png")


def main() -> None:
    s1, ex1 = run("three_bar", 1.0)
    _, ex1_free = run("three_bar", 1.0, impact=False)
    s2, ex2 = run("double_folded", 3.4)
    s4, ex4 = run("three_bar_cycle", 2.3)
    latch = ex1.events[0]["t"]
    sketch_figure(ex1, latch + 0.05, HERE / "sketch_example1.png", others=[ex1_free])
    merge = next(e["t"] for e in ex2.events if e.get("merge"))
    sketch_figure(ex2, merge + 0.1, HERE / "sketch_example2.png")
    first = next(e["t"] for e in ex4.events if e.get("impact"))
    sketch_figure(ex4, first, HERE / "sketch_example4_impact.png")
    release = next(e["t"] for e in ex4.events if e["transition"] == "release")
    sketch_figure(ex4, release + 0.1, HERE / "sketch_example4_release.png")
    graph_figure(record_views(s1), ex1.events, title=s1.name, initial=s1.initial_configuration,
                 path=HERE / "graph_example1.png")
    s2c = pcmm.load_scene(ROOT / "examples" / "double_folded_cycle.toml")
    graph_figure(record_views(s2c), title=s2c.name, initial=s2c.initial_configuration,
                 path=HERE / "graph_example2_cycle.png")
    graph_figure(ex4.views, ex4.events, title=s4.name, initial=s4.initial_configuration,
                 path=HERE / "graph_example4.png")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        write_html(ex4, tmp / "ex4.html", fps=30)
        chromium_shot(tmp / "ex4.html", first, HERE / "replay_example4_impact.png")
        chromium_shot(tmp / "ex4.html", release + 0.1, HERE / "replay_example4_release.png")
        write_html(ex1, tmp / "two.html", fps=30, others=[ex1_free], layout="side")
        chromium_shot(tmp / "two.html", latch + 0.05, HERE / "replay_example1_side.png")
        write_html(ex4, tmp / "follow.html", fps=30, view="follow")
        chromium_shot(tmp / "follow.html", release + 0.1, HERE / "replay_example4_follow.png")
    for f in sorted(HERE.glob("*.png")):
        print(f)


if __name__ == "__main__":
    if sys.argv[1:] == ["pages"]:
        example_pages()
    else:
        main()
        example_pages()
