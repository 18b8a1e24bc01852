"""The engineer's drawing of a recorded run (pcmm.viz.sketch, pcmm.viz.draw2d): symbols where the
URDFs and the scene put them, locks exactly while they hold, the event plates' words and fading,
joint-stop moments as arcs.  Checked against the scene files and the event records, read here by
their own route."""
from __future__ import annotations

import math
import tomllib
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

import pcmm
from pcmm.results.trajectory import Trajectory
from pcmm.viz import sketch as sk
from pcmm.viz.draw2d import Sketch, sketch_figure

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def cycle(tmp_path_factory):
    """Example 4 to 1.3 s: settling, O2 locks, folded, O2's release at 1.199 s; saved and loaded."""
    traj = pcmm.simulate(pcmm.load_scene(ROOT / "examples" / "three_bar_cycle.toml"), pcmm.RunOptions(t_end=1.3))
    path = tmp_path_factory.mktemp("views") / "cycle.npz"
    traj.save(path)
    return Trajectory.load(path)


@pytest.fixture(scope="module")
def double_folded(tmp_path_factory):
    traj = pcmm.simulate(pcmm.load_scene(ROOT / "examples" / "double_folded.toml"), pcmm.RunOptions(t_end=3.4))
    path = tmp_path_factory.mktemp("views") / "df.npz"
    traj.save(path)
    return Trajectory.load(path)


def _urdf_origin(path: Path, joint: str) -> tuple[float, float]:
    j = next(j for j in ET.parse(path).getroot().findall("joint") if j.get("name") == joint)
    x, y, _ = (float(v) for v in j.find("origin").get("xyz").split())
    return x, y


def _configuration_by_events(traj, t: float) -> str:
    """The configuration at ``t`` from the event records alone (each event's ``to``)."""
    conf = traj.segments[0].configuration
    for e in traj.events:
        if e["t"] <= t:
            conf = e["to"]
    return conf


def test_fixed_pivots_sit_at_their_urdf_origins_on_the_frame(cycle, double_folded):
    for traj, urdf, joint in ((cycle, "three_bar_config1.urdf", "O1"),
                              (double_folded, "double_folded_config1.urdf", "A")):
        x, y = _urdf_origin(ROOT / "urdf" / urdf, joint)
        for t in (0.0, float(traj.t[-1])):
            placed = [p for p in sk.world(traj, sk.symbols(traj), t) if p.symbol.kind == "pivot"]
            assert [p.symbol.name for p in placed] == [joint]
            assert placed[0].xy == pytest.approx((x, y), abs=1e-12)


def test_the_locked_symbol_is_present_exactly_while_the_lock_holds(cycle):
    scene = tomllib.loads((ROOT / "examples" / "three_bar_cycle.toml").read_text())
    locks = {c: set(v.get("lock", [])) for c, v in scene["configurations"].items()}
    syms = sk.symbols(cycle)
    # instants: just after every event and midway between events
    ts = sorted({e["t"] + 1e-7 for e in cycle.events}
                | {0.5 * (a["t"] + b["t"]) for a, b in zip(cycle.events, cycle.events[1:])})
    seen = {"O2": [False, False], "O3": [False, False]}
    for t in ts:
        held = locks[_configuration_by_events(cycle, t)]
        drawn = {p.symbol.name for p in sk.world(cycle, syms, t) if p.symbol.kind == "locked"}
        open_circles = {p.symbol.name for p in sk.world(cycle, syms, t) if p.symbol.kind == "revolute"}
        assert drawn == held, t
        assert open_circles == {"O1", "O2", "O3"} - held, t
        for j in seen:
            seen[j][j in held] = True
    assert all(all(v) for v in seen.values()), "each joint must be seen both locked and free"


def test_a_merged_slider_is_a_filled_square_at_the_slider_and_the_stop_is_where_the_scene_puts_it(double_folded):
    merge = next(e for e in double_folded.events if e.get("merge"))
    syms = sk.symbols(double_folded)
    before = {p.symbol.kind for p in sk.world(double_folded, syms, merge["t"] - 1e-3) if p.symbol.name == "E"}
    after = [p for p in sk.world(double_folded, syms, merge["t"] + 1e-3) if p.symbol.name == "E"]
    assert "locked" not in before and "slider" in before
    square = next(p for p in after if p.symbol.kind == "locked")
    assert square.symbol.shape == "square"
    assert square.xy == pytest.approx(tuple(sk.pose_at(double_folded, "slider", merge["t"] + 1e-3)[:2]), abs=1e-12)
    stop = next(p for p in sk.world(double_folded, syms, merge["t"] + 1e-3) if p.symbol.kind == "stop")
    assert stop.symbol.name == "slider stop E"
    assert stop.xy == pytest.approx((0.3195, -0.1425), abs=1e-12)  # the scene's contact point_a on the frame
    assert math.cos(stop.angle) == pytest.approx(-1.0)  # its face across the normal (-1, 0)
    cut = next(p for p in sk.world(double_folded, syms, 1.0) if p.symbol.kind == "cut")
    link2 = sk.pose_at(double_folded, "link2", 1.0)
    assert cut.xy == pytest.approx((link2[0] + 0.2 * math.cos(link2[2]), link2[1] + 0.2 * math.sin(link2[2])),
                                   abs=1e-12)  # C at point_a = (0.2, 0) on link2


def test_plates_say_what_happened_and_are_gone_a_second_later(cycle, double_folded):
    plates = [m for m in sk.event_marks(cycle) if m.kind == "plate"]
    first = cycle.events[0]
    assert first["transition"] == "stop" and not first["merge"]
    assert plates[0].text == f"impact, {first['kind']}, e = 0.8"
    release = next(p for p in plates if p.text.startswith("release"))
    assert release.text == "release (tensile hold)"
    # a macro-impact is one plate with its count: events of one stop up to its merge
    macro = next(p for p in plates if p.text.startswith("macro-impact") and p.text.endswith(", merge"))
    group = [cycle.events[i] for i in macro.extra["events"]]
    assert len({e["name"] for e in group}) == 1 and group[-1]["merge"] and not any(e["merge"] for e in group[:-1])
    assert macro.text.startswith(f"macro-impact ({len(group)} impacts), ")
    # every event is in exactly one plate
    assert sorted(i for p in plates for i in p.extra["events"]) == list(range(len(cycle.events)))
    for p in plates:
        t_last = cycle.events[p.extra["events"][-1]]["t"]
        assert p.alpha(p.window[0]) == 1.0
        assert not p.shown(sk.configuration_at(cycle, t_last + 1.0), t_last + 1.0)
    latch = pcmm.simulate(pcmm.load_scene(ROOT / "examples" / "three_bar.toml"), pcmm.RunOptions(t_end=0.3))
    assert [m.text for m in sk.event_marks(latch) if m.kind == "plate"] == ["latch: impact + merge"]


def test_a_plate_rides_on_its_body(cycle):
    plate = next(m for m in sk.event_marks(cycle) if m.kind == "plate" and m.text.startswith("release"))
    ev = cycle.events[plate.extra["events"][0]]
    t0 = ev["t"]
    at = next(p for p in sk.world(cycle, [plate], t0))
    assert at.xy == pytest.approx(tuple(ev["contact_point"][:2]), abs=1e-9)
    # 0.2 s later it is where the body carried the contact point (body b = O2's child, link2)
    pose0, pose1 = sk.pose_at(cycle, "link2", t0), sk.pose_at(cycle, "link2", t0 + 0.2)
    local = sk.to_local(pose0, ev["contact_point"])
    later = next(p for p in sk.world(cycle, [plate], t0 + 0.2))
    assert later.xy == pytest.approx(sk.to_world(pose1, local), abs=1e-12)
    assert math.dist(later.xy, at.xy) > 1e-3  # it moved with the body
    assert later.alpha == pytest.approx(1 - 0.2 / sk.PLATE_S)


def test_joint_stop_impulses_are_moment_arcs_in_newton_metre_seconds(cycle):
    arcs = [m for m in sk.event_marks(cycle) if m.kind == "arc"]
    impacts = [e for e in cycle.events if e.get("impact")]
    assert len(arcs) == len(impacts)
    for arc in arcs:
        ev = cycle.events[arc.extra["event"]]
        assert arc.name == ev["impulse"]["joint"]
        # the moment is the impulse's force times its arm (the record's own two numbers)
        assert arc.extra["moment"] == pytest.approx(ev["impulse"]["normal"] * ev["impulse"]["arm"], rel=1e-12)
        assert arc.text == f"M = {arc.extra['moment']:.3g} N·m·s"
        assert arc.window[0] == ev["t"]


def test_the_sketch_figure_draws_each_symbol_and_names_the_links(cycle, tmp_path):
    t = next(e["t"] for e in cycle.events if e.get("impact")) + 1e-9
    fig = sketch_figure(cycle, t, tmp_path / "s.png")
    assert (tmp_path / "s.png").stat().st_size > 5000
    gids = [a.get_gid() for a in fig.findobj() if a.get_gid()]
    assert gids.count("pivot:O1") == 1
    assert any(g.startswith("arc:") for g in gids) and any(g.startswith("plate:") for g in gids)
    legend = fig.legends[0]
    assert [t.get_text() for t in legend.get_texts()] == cycle.links
