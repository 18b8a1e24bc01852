"""Figures: the set written follows the data; every file is a real, non-blank PNG."""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

import pcmm
from pcmm.trajectory import SegmentRecord, Trajectory

pytest.importorskip("matplotlib")
from pcmm import plots  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "examples" / "three_bar.toml"
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
BASE = {"link_angles.png", "angular_velocities.png", "relative_angles.png", "force_elements.png", "energy.png"}


@pytest.fixture(scope="module")
def runs():
    scene = pcmm.load_scene(SCENE)
    opts = dict(t_end=0.5)
    return (pcmm.simulate(scene, pcmm.RunOptions(**opts)),
            pcmm.simulate(scene, pcmm.RunOptions(**opts, impact=False)))


def assert_png(path: Path):
    import matplotlib.image as mpimg
    data = path.read_bytes()
    assert data[:8] == PNG_MAGIC, path
    assert len(data) > 10_000, f"{path}: suspiciously small ({len(data)} bytes)"
    img = mpimg.imread(path)
    h, w = img.shape[:2]
    assert w >= 600 and h >= 300, (path, w, h)
    assert img[..., :3].std() > 0.02, f"{path}: blank image"


def test_three_bar_with_and_without_impact(runs, tmp_path):
    out = tmp_path / "figs"  # created by write_figures
    files = plots.write_figures(runs[0], out, compare=runs[1])
    assert {f.name for f in files} == BASE | {"impulses.png"}
    assert sorted(p.name for p in out.iterdir()) == sorted(f.name for f in files), "no stray files"
    for f in files:
        assert f.parent == out
        assert_png(f)


def test_no_impact_run_alone_has_no_impulse_figure(runs, tmp_path):
    files = plots.write_figures(runs[1], tmp_path)
    assert {f.name for f in files} == BASE
    for f in files:
        assert_png(f)


def test_compare_order_does_not_matter(runs, tmp_path):
    """``pcmm run --no-impact --plots`` passes the run with impact as ``compare``."""
    files = plots.write_figures(runs[1], tmp_path, compare=runs[0])
    assert {f.name for f in files} == BASE | {"impulses.png"}
    labels = [r.label for r in plots._runs(runs[1], runs[0])]
    assert labels == [plots.WITHOUT_IMPACT, plots.WITH_IMPACT]


def test_missing_matplotlib_is_a_usage_error(runs, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    with pytest.raises(pcmm.UsageError, match=r"pip install 'pcmm\[plots\]'"):
        plots.write_figures(runs[0], tmp_path)


# ---- a synthetic run with a slider, a drive and a macro-impact (the figures of Example 2) ----
def _segment(config, t, with_slider_coord):
    n = len(t)
    crank = math.pi + math.pi / 5 * t
    x = 0.2 + 0.1 * np.sin(t)
    theta = np.column_stack([np.zeros(n), crank, np.zeros(n)])
    omega = np.column_stack([np.zeros(n), np.full(n, math.pi / 5), np.zeros(n)])
    xy = np.zeros((n, 3, 2))
    xy[:, 1] = [0.0, 0.0]
    xy[:, 2, 0] = x
    xy[:, 2, 1] = -0.1425
    coords = ["A", "S"] if with_slider_coord else ["A"]
    q = np.column_stack([crank, x][: len(coords)])
    v = np.column_stack([omega[:, 1], 0.1 * np.cos(t)][: len(coords)])
    return SegmentRecord(configuration=config, coordinates=coords, links=["frame", "crank", "slider"],
                         force_names=["spring"], constraint_labels=["A.drive"], t=t, q=q, v=v, theta=theta,
                         omega=omega, xy=xy, kinetic=0.5 * v[:, -1] ** 2, potential=np.sin(t),
                         forces=np.cos(t)[:, None], constraint_forces=0.2 * np.sin(3 * t)[:, None])


def _synthetic(impact: bool) -> Trajectory:
    segs = [_segment("c1", np.linspace(0.0, 3.0, 300), True), _segment("c2", np.linspace(3.0, 7.0, 400), False)]
    events = []
    for k in range(6):  # a macro-impact: six micro-impacts at 3.0 s, closer and closer
        t = 3.0 + 0.01 * (1 - 0.5 ** k)
        events.append({"t": t, "kind": "stable", "transition": "stop", "from": "c1",
                       "to": "c2" if k == 5 else "c1", "merge": k == 5, "impact": impact,
                       "impulse": {"normal": -0.05 * 0.5 ** k if impact else 0.0, "vector": [0.0, 0.0]},
                       "contact_point": [0.3, -0.1425]})
    return Trajectory(scene="/nonexistent/double_folded.toml", scene_name="synthetic", impact=impact,
                      segments=segs, events=events)


def test_slider_drive_and_impulse_figures_follow_the_data(tmp_path):
    with_impact, without = _synthetic(True), _synthetic(False)
    files = plots.write_figures(with_impact, tmp_path, compare=without)
    names = {f.name for f in files}
    # one rotating link: no relative angle; a translating link: the slider figure
    assert names == {"link_angles.png", "angular_velocities.png", "force_elements.png", "energy.png",
                     "impulses.png", "slider.png", "driving_moment.png"}
    for f in files:
        assert_png(f)


def test_slider_position_and_velocity(tmp_path):
    traj = _synthetic(True)
    (slider,) = plots._sliders(traj, None, {})
    assert slider.name == "slider" and slider.symbol == "$x$"
    run = plots._runs(traj, None)[0]
    assert np.allclose(slider.position(run), 0.2 + 0.1 * np.sin(traj.t))
    assert np.allclose(slider.velocity(run), 0.1 * np.cos(traj.t), atol=1e-5)


def test_run_without_events_marks_nothing(tmp_path):
    traj = _synthetic(True)
    traj.events = []
    files = plots.write_figures(traj, tmp_path)
    assert "impulses.png" not in {f.name for f in files}
