"""Figures: the set written follows the data; every file is a real, non-blank PNG."""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

import pcmm
from pcmm.results.trajectory import SegmentRecord, Trajectory

pytest.importorskip("matplotlib")
from pcmm.viz import plots  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "examples" / "three_bar.toml"
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
BASE = {"link_angles.png", "angular_velocities.png", "relative_angles.png", "force_elements.png", "energy.png",
        "graph.png"}  # every run of a scene with transitions draws its working cycle


@pytest.fixture(scope="module")
def runs():
    scene = pcmm.load_scene(SCENE)
    opts = dict(t_end=0.5)
    return (pcmm.simulate(scene, pcmm.RunOptions(**opts)),
            pcmm.simulate(scene, pcmm.RunOptions(**opts, impact=False)))


@pytest.fixture(scope="module")
def written(runs, tmp_path_factory):
    """``write_figures(runs[0], out, compare=runs[1])``: (out, the files), drawn once for the two
    tests that read them (the figures, drawn and saved, are most of a test's time)."""
    out = tmp_path_factory.mktemp("plots") / "figs"  # created by write_figures
    return out, plots.write_figures(runs[0], out, compare=runs[1])


def assert_png(path: Path):
    import matplotlib.image as mpimg
    data = path.read_bytes()
    assert data[:8] == PNG_MAGIC, path
    assert len(data) > 10_000, f"{path}: suspiciously small ({len(data)} bytes)"
    img = mpimg.imread(path)
    h, w = img.shape[:2]
    assert w >= 600 and h >= 300, (path, w, h)
    assert img[..., :3].std() > 0.02, f"{path}: blank image"


def test_three_bar_with_and_without_impact(written):
    out, files = written
    assert {f.name for f in files} == BASE | {"impulses.png", "holding_forces.png", "angle_differences.png"}
    assert sorted(p.name for p in out.iterdir()) == sorted(f.name for f in files), "no stray files"
    for f in files:
        assert f.parent == out
        assert_png(f)


def test_no_impact_run_alone_has_no_impulse_figure(runs, tmp_path):
    files = plots.write_figures(runs[1], tmp_path)
    assert {f.name for f in files} == BASE | {"holding_forces.png"}  # the lock holds without an impact too
    for f in files:
        assert_png(f)


def test_compare_order_does_not_matter(runs, tmp_path):
    """``pcmm run --no-impact --plots`` passes the run with impact as ``compare``."""
    files = plots.write_figures(runs[1], tmp_path, compare=runs[0])
    assert {f.name for f in files} == BASE | {"impulses.png", "holding_forces.png", "angle_differences.png"}
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
                     "impulses.png", "slider.png", "driving_moment.png", "angle_differences.png"}
    for f in files:
        assert_png(f)


def test_slider_position_and_velocity(tmp_path):
    traj = _synthetic(True)
    (slider,) = plots._sliders(traj, {})
    assert slider.name == "slider" and slider.symbol == "$x$"
    run = plots._runs(traj, None)[0]
    assert np.allclose(slider.position(run), 0.2 + 0.1 * np.sin(traj.t))
    assert np.allclose(slider.velocity(run), 0.1 * np.cos(traj.t), atol=1e-5)


def test_run_without_events_marks_nothing(tmp_path):
    traj = _synthetic(True)
    traj.events = []
    files = plots.write_figures(traj, tmp_path)
    assert "impulses.png" not in {f.name for f in files}


# ---- what the figures state ---------------------------------------------------------------------
def _stems(ax):
    (stem,) = [c for c in ax.containers if hasattr(c, "markerline")]
    return stem.markerline.get_xdata(), stem.markerline.get_ydata()


def test_figures_returns_the_figures_write_figures_saves(runs, written):
    from matplotlib.figure import Figure
    figs = runs[0].plot(compare=runs[1])
    assert all(isinstance(f, Figure) for f in figs.values())
    _, files = written  # write_figures(runs[0], out, compare=runs[1])
    assert [f.stem for f in files] == list(figs)


def test_impulse_sign_convention_is_stated_and_the_paper_one_is_an_option(runs):
    ev = next(e for e in runs[0].events if e.get("impact"))
    P = ev["impulse"]["normal"]
    assert P > 0  # on body b (link 3), along the normal from a to b
    ours = plots.figures(runs[0])["impulses"].axes[0]
    t, p = _stems(ours)
    assert list(t) == [ev["t"]] and list(p) == [P]
    assert ours.get_title().startswith("$P_n > 0$: the impulse on body b along the contact normal n")
    assert "impulse_sign='paper'" in ours.get_title()
    paper = plots.figures(runs[0], impulse_sign="paper")["impulses"].axes[0]
    assert list(_stems(paper)[1]) == [-P]
    assert "paper's sign" in paper.get_title() and "paper's sign" in paper.get_ylabel()
    with pytest.raises(pcmm.UsageError, match="impulse_sign = 'other'"):
        plots.figures(runs[0], impulse_sign="other")


def _legend_texts(fig):
    return [t.get_text() for lg in fig.legends for t in lg.get_texts()]


def _vlines(ax):
    return [(line.get_xdata()[0], line.get_color(), line.get_linestyle()) for line in ax.get_lines()
            if len(line.get_xdata()) == 2 and line.get_xdata()[0] == line.get_xdata()[1]]


def test_every_event_is_marked_and_a_macro_impact_is_summarised():
    traj = _synthetic(True)
    traj.events.append({"t": 5.0, "name": "stop", "kind": "stable", "transition": "release", "from": "c2",
                        "to": "c1", "merge": False, "impact": False,
                        "impulse": {"normal": 0.0, "vector": [0.0, 0.0]}, "contact_point": [0.3, -0.1425]})
    figs = plots.figures(traj)
    first, last = traj.events[0]["t"], traj.events[5]["t"]
    legend = _legend_texts(figs["link_angles"])
    # six impacts in 0.01 s: one entry and one shaded span, not six legend lines; then the merge and the release
    assert legend[1:] == [f"6 impacts, t = {first:.4f} ... {last:.4f} s", f"merge, t = {last:.4f} s",
                          "release, t = 5.0000 s"]
    ax = figs["link_angles"].axes[0]
    lines = _vlines(ax)
    assert {(round(x, 12), ls) for x, _, ls in lines} == {(round(first, 12), ":"), (round(last, 12), ":"),
                                                            (round(last, 12), "-."), (5.0, "--")}
    spans = [p for p in ax.patches if p.get_alpha() and p.get_alpha() < 0.5]
    assert len(spans) == 1
    x0, x1 = spans[0].get_x(), spans[0].get_x() + spans[0].get_width()
    assert math.isclose(x0, first) and math.isclose(x1, last)
    # the impulse figure marks them too
    assert "release, t = 5.0000 s" in _legend_texts(figs["impulses"])


def test_many_single_events_get_one_counting_legend_entry():
    traj = _synthetic(True)
    traj.events = [dict(traj.events[0], t=float(t), merge=False) for t in (1.0, 2.0, 3.0, 4.0, 5.0)]
    legend = _legend_texts(plots.figures(traj)["link_angles"])
    assert legend[1:] == ["5 impacts, t = 1.0000 ... 5.0000 s"]
    assert len(_vlines(plots.figures(traj)["link_angles"].axes[0])) == 5


def test_no_impact_energy_change_is_annotated(runs):
    without = runs[1]
    (t, dke), = plots.switch_energy_changes(without)
    # an independent route: the run's own kinetic energy on either side of the switch
    before, after = without.segments[0], without.segments[1]
    assert before.t[-1] == after.t[0] == t
    assert math.isclose(dke, after.kinetic[0] - before.kinetic[-1], rel_tol=1e-9)
    assert dke < 0  # Example 1: dropping O3's relative speed takes 0.344 J here
    ax = plots.figures(runs[0], compare=without)["energy"].axes[0]
    title = ax.get_title()
    assert f"−{abs(dke):.4g} J at t = {t:.4f} s" in title and "no conservation law" in title
    assert f"{dke:+.3g} J" in [t.get_text() for t in ax.texts]  # the arrow at the switch
    assert "Without impact" not in plots.figures(runs[0])["energy"].axes[0].get_title()


def test_plot_after_the_scene_and_urdfs_are_deleted(tmp_path):
    import shutil
    from pcmm.cli import main
    from scene_files import copy_example1
    scene = copy_example1(tmp_path)
    npz = tmp_path / "run.npz"
    assert main(["run", str(scene), "--t-end", "0.3", "--out", str(npz), "--quiet"]) == 0
    shutil.rmtree(tmp_path / "urdf")
    scene.unlink()
    assert main(["plot", str(npz), "--out", str(tmp_path / "figs")]) == 0
    assert {p.name for p in (tmp_path / "figs").iterdir()} == BASE | {"impulses.png", "holding_forces.png"}
    # the units come from the recorded views: the torques act on links (N·m), not "N·m or N"
    figs = plots.figures(pcmm.Trajectory.load(npz))
    panels = [ax for ax in figs["force_elements"].axes if ax.get_visible()]
    assert [ax.get_ylabel() for ax in panels] == [
        r"$\tau_{1}$ (N·m)", r"$\tau_{2}$ (N·m)", r"$\tau_{3}$ (N·m)"]
    assert [ax.get_title() for ax in panels] == [
        "(a) tau1 on link1", "(b) tau2 on link2", "(c) tau3 on link3"]


def test_the_holding_figure_plots_each_locks_recorded_hold(runs):
    """One panel per lock: O3's holding moment (a latch on a revolute joint: N·m), the very series
    the trajectory records (NaN before the latch), for the run with impact and the one without."""
    fig = plots.figures(runs[0], compare=runs[1])["holding_forces"]
    (ax,) = [a for a in fig.axes if a.get_visible()]
    assert ax.get_ylabel() == "moment (N·m)" and ax.get_title() == "(a) Holding moment of O3"
    curves = {line.get_label(): line for line in ax.get_lines()}
    for label, run in ((plots.WITH_IMPACT, runs[0]), (plots.WITHOUT_IMPACT, runs[1])):
        np.testing.assert_array_equal(curves[label].get_ydata(), run.series("constraint_forces", "O3.hold"))


@pytest.mark.parametrize("t_end", [0.2, 1.0, 3.0])
def test_the_first_impulse_label_stays_inside_the_axes(t_end):
    """Example 1's latch at 0.167 s labelled on a time axis of 0.2, 1 and 3 s: the label sits
    left of the stem unless the stem is in the axes' left third, and never runs over the y axis
    or past the right edge (a newcomer's five-bar, first impact at 0.095 of 1 s, had it over the
    tick labels)."""
    traj = pcmm.simulate(SCENE, pcmm.RunOptions(t_end=t_end))
    fig = traj.plot()["impulses"]
    ax = fig.axes[0]
    (label,) = [t for t in ax.texts if "N·s" in t.get_text()]
    fig.canvas.draw()
    box, frame = label.get_window_extent(), ax.get_window_extent()
    assert box.x0 >= frame.x0 and box.x1 <= frame.x1, (t_end, box, frame)
    assert label.get_ha() == ("left" if 0.167 < t_end / 3 else "right")


def test_the_difference_of_the_two_runs_is_plotted_zero_until_the_first_event(runs):
    """The run without impact hides under the one with impact where they agree: the difference
    figure shows theta_with - theta_without, read back from its own curve."""
    with_impact, without = runs
    fig = plots.figures(with_impact, compare=without)["angle_differences"]
    t_event = with_impact.events[0]["t"]
    panels = [ax for ax in fig.axes if ax.get_visible()]
    assert [ax.get_title().split("Difference of ")[1].split("'")[0] for ax in panels] == ["link1", "link2", "link3"]
    for ax, link in zip(panels, ["link1", "link2", "link3"]):
        (curve,) = [ln for ln in ax.get_lines() if ln.get_color() == "C4"]
        t, d = curve.get_xdata(), curve.get_ydata()
        expect = with_impact.series("theta", link) - np.interp(with_impact.t, without.t, without.series("theta", link))
        assert np.array_equal(t, with_impact.t) and np.allclose(d, expect, atol=1e-15)
        assert np.abs(d[t < t_event - 1e-9]).max() < 1e-9  # the same run until the latch
        assert np.abs(d[t > t_event + 0.05]).max() > 1e-3  # and apart after it
        assert any(abs(x - t_event) < 1e-12 for ln in ax.get_lines() for x in np.atleast_1d(ln.get_xdata())[:1])


# ---- pcmm run --plots: the comparison run, and --no-comparison -------------------------------
def _run_plots(tmp_path, monkeypatch, capsys, *flags):
    """``pcmm run BALL --plots figs FLAGS`` in-process: the impact flag of every simulate call,
    the ``compare`` the figures got, the figures drawn (before saving) and the files written."""
    import builders
    from pcmm.cli import main as cli_main
    from pcmm.run import loop
    calls, drawn = [], []
    real_simulate, real_figures = loop.simulate, plots.figures

    def simulate(scene, opts=None, *a, **kw):
        calls.append(opts.impact)
        return real_simulate(scene, opts, *a, **kw)

    def figures(traj, compare=None, **kw):
        drawn.append((traj, compare, real_figures(traj, compare=compare, **kw)))
        return drawn[-1][2]
    monkeypatch.setattr(loop, "simulate", simulate)
    monkeypatch.setattr(plots, "figures", figures)
    # a ball dropped from 1 m hits the floor at t = sqrt(2/g) = 0.45 s: one transition, one impact
    scene = builders.ball(tmp_path / "scene", 0.5, t_end=0.6)
    out = tmp_path / "figs"
    rc = cli_main(["run", str(scene), "--plots", str(out), "--quiet", *flags])
    _, err = capsys.readouterr()
    assert rc == 0, err
    (traj, compare, figs), = drawn
    return calls, compare, figs, sorted(p.name for p in out.iterdir()), err


def _legend(fig) -> list[str]:
    return [t.get_text() for leg in fig.legends for t in leg.get_texts()]


def test_run_plots_draws_the_comparison_run_by_default(tmp_path, monkeypatch, capsys):
    calls, compare, figs, names, _ = _run_plots(tmp_path, monkeypatch, capsys)
    assert calls == [True, False]  # this run, then the comparison run without impact
    assert compare is not None and compare.impact is False
    assert names == sorted(f"{k}.png" for k in figs) and "energy.png" in names
    legend = _legend(figs["energy"])
    assert any(plots.WITH_IMPACT.lower() in s.lower() for s in legend)
    assert any(plots.WITHOUT_IMPACT.lower() in s.lower() for s in legend)


def test_no_comparison_runs_once_and_draws_this_run_alone(tmp_path, monkeypatch, capsys):
    calls, compare, figs, names, err = _run_plots(tmp_path, monkeypatch, capsys, "--no-comparison")
    assert calls == [True] and compare is None  # one simulation: no second run without impact
    assert "comparison run" not in err
    # the figures of this run, each written as a PNG (the ball has no link angle to difference)
    assert {"energy.png", "impulses.png", "slider.png"} <= set(names)
    assert names == sorted(f"{k}.png" for k in figs)
    for n in names:
        assert_png(tmp_path / "figs" / n)
    legend = _legend(figs["energy"])  # one run: the curves are not tagged with or without impact
    assert "Kinetic energy" in legend and not any("impact motion" in s for s in legend)
    assert not any(plots.WITHOUT_IMPACT in s for f in figs.values() for s in _legend(f))


def test_no_comparison_without_plots_is_a_usage_error(tmp_path, capsys):
    import builders
    from pcmm.cli import main as cli_main
    scene = builders.ball(tmp_path / "scene", 0.5, t_end=0.1)
    assert cli_main(["run", str(scene), "--no-comparison", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "--no-comparison" in err and "--plots" in err and "Traceback" not in err
