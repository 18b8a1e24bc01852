"""Replay: the offline HTML page and the live meshcat server.

Most tests need no browser: they decode the meshcat commands embedded in the
page (msgpack, base64 strings of ``PCMM_COMMANDS``, handled in order) and check
the one animation it carries, the timeline and the page's data.  The
``browser`` tests render the page in headless Chromium (``page.html#t=<seconds>``).
"""
from __future__ import annotations

import base64
import dataclasses
import json
import math
import os
import re
import types
from pathlib import Path

import numpy as np
import pytest

import headless
import pcmm
from pcmm.viz import replay
from pcmm.viz import sketch as sk
from pcmm.viz.page import IMAGE_REF

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "examples" / "three_bar.toml"
FPS = 60
T_END = 0.4

try:
    import umsgpack as _msgpack  # meshcat's own dependency

    def _unpack(b):
        return _msgpack.unpackb(b)
except ImportError:  # pragma: no cover
    import msgpack as _msgpack

    def _unpack(b):
        return _msgpack.unpackb(b, raw=False)

_COMMANDS = re.compile(r"var PCMM_COMMANDS = \[(.*?)\];", re.S)
_DATA = re.compile(r'<script type="application/json" id="pcmm-data">(.*?)</script>', re.S)


_IMAGES = re.compile(r"var PCMM_IMAGES = (\[.*?\]);", re.S)


def decode_commands(html: str) -> list[dict]:
    """The page's meshcat commands as meshcat reads them: each texture's ``pcmm-image:<i>``
    replaced by the page's picture ``i`` (as the page's script does)."""
    (block,) = _COMMANDS.findall(html)
    (table,) = _IMAGES.findall(html)
    images = json.loads(table.replace("<\\/", "</"))
    commands = [_unpack(base64.b64decode(m)) for m in re.findall(r'"([A-Za-z0-9+/=]+)"', block)]
    for c in commands:
        for image in c.get("object", {}).get("images", []) if c["type"] == "set_object" else []:
            assert image["url"].startswith(IMAGE_REF), "a picture inlined in a command, not in the table"
            image["url"] = images[int(image["url"][len(IMAGE_REF):])]
    return commands


def page_data(html: str) -> dict:
    (text,) = _DATA.findall(html)
    return json.loads(text.replace("<\\/", "</"))


def clips_of(commands) -> dict[str, dict]:
    """``{node path: {track name ('position', 'visible', ...): (frames, values)}}`` plus fps."""
    anims = [c for c in commands if c["type"] == "set_animation"]
    assert len(anims) == 1, "the page must carry exactly one animation"
    out = {}
    for a in anims[0]["animations"]:
        tracks = {t["name"].lstrip("."): ([k["time"] for k in t["keys"]], [k["value"] for k in t["keys"]])
                  for t in a["clip"]["tracks"]}
        tracks["_fps"] = a["clip"]["fps"]
        out[a["path"]] = tracks
    return out


def value_at(track, frame):
    """A discrete (boolean) track's value at ``frame``: the last key at or before it."""
    frames, values = track
    i = np.searchsorted(frames, frame, side="right") - 1
    assert i >= 0, "no key at or before frame 0"
    return values[i]


@pytest.fixture(scope="module")
def runs():
    scene = pcmm.load_scene(SCENE)
    with_impact = pcmm.simulate(scene, pcmm.RunOptions(t_end=T_END))
    without = pcmm.simulate(scene, pcmm.RunOptions(t_end=T_END, impact=False))
    return with_impact, without


@pytest.fixture(scope="module")
def page(runs, tmp_path_factory):
    path = tmp_path_factory.mktemp("replay") / "replay.html"
    assert replay.write_html(runs[0], path, fps=FPS) == path
    return path


@pytest.fixture(scope="module")
def clips(page):
    return clips_of(decode_commands(page.read_text(encoding="utf-8")))


def _first_impact(traj):
    return next(e for e in traj.events if e.get("impact"))


def _switch_frame(t):
    return math.ceil(t * FPS - 1e-9)  # the first frame at or after t (the run starts at 0)


def test_page_is_self_contained(page):
    html = page.read_text(encoding="utf-8")
    assert html.lstrip().lower().startswith("<!doctype html>")
    assert "new MeshCat.Viewer" in html
    assert not re.search(r"""(src|href)\s*=\s*["']?\s*(https?:|ws:|wss:)?//""", html, re.I), \
        "the page must not load anything from the network"
    assert "viewer.connect(" not in html
    assert not list(page.parent.glob(".replay.html.*.tmp")), "no temporary file left behind"


def _keys(traj):
    """The animation's keys (frames): every k / fps plus each event's exact instant."""
    grid = np.arange(round(float(traj.t[-1] - traj.t[0]) * FPS) + 1, dtype=float)
    events = np.array([(e["t"] - traj.t[0]) * FPS for e in traj.events])
    return np.union1d(grid, events)


def test_one_transform_track_per_link_and_frame_count(runs, clips):
    traj = runs[0]
    duration = float(traj.t[-1] - traj.t[0])
    moving = {p: c for p, c in clips.items() if "position" in c and "/links/" in p}
    assert sorted(moving) == sorted(f"/meshcat/pcmm/links/{link}" for link in traj.links)
    # no other node under links/ moves on its own: the geometry rides on its link's track
    assert not [p for p, c in clips.items() if "quaternion" in c and p not in moving]
    expected = duration * FPS + len(traj.events)  # the uniform frames and one per event
    for path, c in moving.items():
        frames, _ = c["position"]
        assert c["_fps"] == FPS
        assert abs(len(frames) - expected) <= 1, (path, len(frames), expected)
        assert np.array_equal(frames, _keys(traj))
        assert c["quaternion"][0] == frames
        assert math.isclose(frames[-1] / FPS, duration, abs_tol=1.0 / FPS)


def test_a_frame_at_each_event_exact_time(runs, clips):
    """The state at an event is a frame of the animation: a key at exactly (t - t0) * fps, showing
    the pose the run records at t."""
    traj = runs[0]
    assert traj.events
    for ev in traj.events:
        key = (ev["t"] - traj.t[0]) * FPS
        seg = next(s for s in traj.segments if s.t[0] == ev["t"])  # the run restarts at the event
        for j, link in enumerate(seg.links):
            frames, values = clips[f"/meshcat/pcmm/links/{link}"]["position"]
            assert key in frames, (link, ev["t"])
            assert np.allclose(values[frames.index(key)][:2], seg.xy[0, j], rtol=0, atol=1e-12)


def test_link_poses_follow_the_trajectory(runs, clips):
    traj = runs[0]
    last = traj.segments[-1]
    for j, link in enumerate(last.links):
        c = clips[f"/meshcat/pcmm/links/{link}"]
        frames, pos, quat = c["position"][0], c["position"][1], c["quaternion"][1]
        first = traj.segments[0]
        assert np.allclose(pos[0][:2], first.xy[0, first.links.index(link)], atol=1e-12)
        assert np.allclose(pos[-1][:2], last.xy[-1, j], atol=1e-9)
        x, y, z, w = quat[-1]
        assert x == 0 and y == 0
        assert math.isclose(math.cos(last.theta[-1, j]), w * w - z * z, abs_tol=1e-9)
        assert math.isclose(math.sin(last.theta[-1, j]), 2 * w * z, abs_tol=1e-9)
        # a frame in the middle: the link frame origin interpolated at k / fps
        k = int(frames[-1]) // 2
        seg = next(s for s in reversed(traj.segments) if s.t[0] <= k / FPS)
        i = seg.links.index(link)
        expect = [np.interp(k / FPS, seg.t, seg.xy[:, i, 0]), np.interp(k / FPS, seg.t, seg.xy[:, i, 1])]
        assert np.allclose(pos[frames.index(float(k))][:2], expect, atol=1e-12)


def test_configuration_geometry_switches_at_the_event_frame(runs, clips, page):
    traj = runs[0]
    ev = next(e for e in traj.events if e["from"] != e["to"])
    k = _switch_frame(ev["t"])
    assert 0 < k < int(T_END * FPS)
    commands = decode_commands(page.read_text(encoding="utf-8"))
    objects = {c["path"] for c in commands if c["type"] == "set_object"}
    scene = pcmm.load_scene(SCENE)
    for config in (ev["from"], ev["to"]):
        for link, visuals in replay.read_visuals(scene.configurations[config].urdf).items():
            # every configuration's geometry is loaded up front, one node per visual
            for i in range(len(visuals)):
                assert f"/meshcat/pcmm/links/{link}/{config}/visual{i}" in objects
            if not visuals:
                continue
            vis = clips[f"/meshcat/pcmm/links/{link}/{config}"]["visible"]
            before, after = value_at(vis, k - 1), value_at(vis, k)
            if config == ev["from"]:
                assert (before, after) == (True, False), (link, config)
            else:
                assert (before, after) == (False, True), (link, config)
            assert value_at(vis, 0) is (config == ev["from"])
    # the configuration label: exactly one visible at every frame, the active one
    labels = {p.rsplit("/", 1)[1]: c["visible"] for p, c in clips.items() if "/labels/" in p}
    assert set(labels) == {ev["from"], ev["to"]}
    for f in range(int(T_END * FPS) + 1):
        shown = [name for name, track in labels.items() if value_at(track, f)]
        assert shown == [ev["from"] if f < k else ev["to"]], f


def test_impact_marker_flashes_at_the_event_frame(runs, clips):
    traj = runs[0]
    ev = _first_impact(traj)
    k = _switch_frame(ev["t"])
    markers = {p: c for p, c in clips.items() if "/impacts/" in p}
    assert len(markers) == 1
    (track,) = markers.values()
    vis = track["visible"]
    assert value_at(vis, 0) is False and value_at(vis, k - 1) is False
    assert value_at(vis, k) is True
    n_on = sum(value_at(vis, f) for f in range(int(T_END * FPS) + 1))
    assert 3 <= n_on <= round(replay.FLASH_S * FPS) + 1, "a flash lasts a few frames"
    frames, values = track["position"]
    i = np.searchsorted(frames, k, side="right") - 1
    assert np.allclose(values[i][:2], ev["contact_point"], atol=1e-12)


def test_run_without_impact_has_no_marker_but_switches(runs, tmp_path):
    traj = runs[1]
    path = replay.write_html(traj, tmp_path / "no_impact.html", fps=FPS)
    clips = clips_of(decode_commands(path.read_text(encoding="utf-8")))
    assert not [p for p in clips if "/impacts/" in p]
    assert sum("/labels/" in p for p in clips) == 2


def test_camera_is_orthographic_top_down(page):
    commands = decode_commands(page.read_text(encoding="utf-8"))
    cams = [c for c in commands if c["type"] == "set_object" and c["path"] == "/Cameras/default/rotated"]
    assert len(cams) == 1
    cam = cams[0]["object"]["object"]
    assert cam["type"] == "OrthographicCamera"
    m = np.array(cam["matrix"]).reshape(4, 4).T  # column-major
    assert np.allclose(m[:3, :3], np.eye(3)) and m[2, 3] > 0  # on +z, looking down -z, y up
    rotated = [c for c in commands if c["type"] == "set_transform" and c["path"] == "/Cameras/default/rotated"]
    assert np.allclose(np.array(rotated[-1]["matrix"]), np.eye(4).flatten())


# ---- what the page shows ------------------------------------------------------------------
def _objects(commands) -> dict[str, dict]:
    return {c["path"]: c["object"] for c in commands if c["type"] == "set_object"}


def _transforms(commands) -> dict[str, np.ndarray]:
    """Each node's last transform (meshcat sends three.js's column-major order)."""
    return {c["path"]: np.array(c["matrix"], float).reshape(4, 4).T for c in commands if c["type"] == "set_transform"}


def _texture_png(obj) -> bytes:
    (image,) = obj["images"]
    return base64.b64decode(image["url"].split(",", 1)[1])


_MARKER = re.compile(r'<div class="pcmm-marker pcmm-(\w+)" data-run="(\d+)" data-event="(\d+)" data-t="([^"]+)"')


def test_one_timeline_marker_per_event(runs, page):
    html = page.read_text(encoding="utf-8")
    traj = runs[0]
    markers = _MARKER.findall(html)
    assert len(markers) == len(traj.events) >= 1
    for (kind, run, i, t), ev in zip(markers, traj.events):
        assert run == "0" and int(i) == traj.events.index(ev)
        assert float(t) == ev["t"], "the marker seeks to the event's exact time"
        assert kind == replay.event_kind(ev)
    # the latch of Example 1 is a plastic impact that merges link 3 into link 2
    assert [m[0] for m in markers] == ["merge"]
    data = page_data(html)
    assert [e["t"] for e in data["runs"][0]["events"]] == [e["t"] for e in traj.events]


def test_impulse_arrow_length_direction_and_label(runs, page, clips):
    html = page.read_text(encoding="utf-8")
    commands = decode_commands(html)
    objects, transforms = _objects(commands), _transforms(commands)
    data = page_data(html)
    traj = runs[0]
    ev = _first_impact(traj)
    P = ev["impulse"]["normal"]
    # the README's value for Example 1's latch impulse, and the label the arrow carries
    assert math.isclose(abs(P), 0.33090, abs_tol=5e-6)
    (entry,) = [e for e in data["runs"][0]["events"] if e["t"] == ev["t"]]
    assert entry["label"] == "P = 0.3309 N·s" and entry["impulse"] == P
    label = objects["/meshcat/pcmm/arrows/0/label"]
    assert _texture_png(label) == replay._label_png("P = 0.3309 N·s", **replay.ARROW_LABEL)[0]
    # length: shaft + head = scale * |P|, the scale the page's legend states
    shaft = objects["/meshcat/pcmm/arrows/0/arrow/shaft"]["geometries"][0]
    head = objects["/meshcat/pcmm/arrows/0/arrow/head"]["geometries"][0]
    assert head["type"] == "CylinderGeometry" and head["radiusTop"] == 0
    assert math.isclose(shaft["height"] + head["height"], data["arrow_scale"] * abs(P), rel_tol=1e-12)
    assert f"1 N·s = {data['arrow_scale']:.3g} m" in html
    # position and direction: from the contact point along P n (the impulse on body b)
    assert np.allclose(transforms["/meshcat/pcmm/arrows/0"][:2, 3], ev["contact_point"], atol=1e-12)
    y_axis = transforms["/meshcat/pcmm/arrows/0/arrow"][:2, 1]
    assert np.allclose(y_axis * abs(P), ev["impulse"]["vector"], atol=1e-12)
    # visible from the impact's own frame, not one frame before, and gone after the flash
    vis = clips["/meshcat/pcmm/arrows/0"]["visible"]
    key = (ev["t"] - traj.t[0]) * FPS
    assert key in vis[0]
    assert value_at(vis, key) is True and value_at(vis, key - 1e-6) is False
    assert value_at(vis, key + (replay.FLASH_S + 2 / FPS) * FPS) is False


def _strip_materials(traj):
    def strip(text):
        text = re.sub(r"<material\b[^>]*[^/]>.*?</material>", "", text, flags=re.S)
        return re.sub(r"<material\b[^>]*/>", "", text)
    views = {c: dict(v, urdf=strip(v["urdf"])) for c, v in traj.views["configurations"].items()}
    assert all("<material" not in v["urdf"] for v in views.values())
    return dataclasses.replace(traj, views={**traj.views, "configurations": views})


def _link_colours(commands, root="/meshcat/pcmm/links/"):
    out: dict[str, set] = {}
    for path, obj in _objects(commands).items():
        if path.startswith(root) and "/visual" in path:
            out.setdefault(path[len(root):].split("/")[0], set()).add(obj["materials"][0]["color"])
    return out


def test_colours_differ_per_link_where_the_urdf_gives_none(runs):
    plain = _strip_materials(runs[0])
    colours = _link_colours(decode_commands(replay.html_page(plain, fps=FPS)))
    moving = ["link1", "link2", "link3"]
    assert all(len(colours[link]) == 1 for link in colours), "a link keeps its colour in every configuration"
    picked = [next(iter(colours[link])) for link in moving]
    assert len(set(picked)) == 3, picked
    assert colours["frame"] == {replay._rgba_int(replay._GREY)} and colours["frame"].isdisjoint(picked)
    # a URDF colour wins: link1's <material> in three_bar_config1.urdf is 0.85 0.33 0.10
    given = _link_colours(decode_commands(replay.html_page(runs[0], fps=FPS)))
    assert (217 << 16) | (84 << 8) | 26 in given["link1"]


def _camera(commands):
    (cam,) = [c["object"]["object"] for c in commands
              if c["type"] == "set_object" and c["path"] == "/Cameras/default/rotated"]
    return cam


def test_fitted_view_contains_every_link_at_every_frame(runs, page, clips):
    """Every visual's corners, placed by the page's own tracks at every key, lie inside the
    camera's window; and the mechanism fills most of that window."""
    commands = decode_commands(page.read_text(encoding="utf-8"))
    cam = _camera(commands)
    objects, transforms = _objects(commands), _transforms(commands)
    lo, hi = np.full(2, np.inf), np.full(2, -np.inf)
    for path, obj in objects.items():
        if not path.startswith("/meshcat/pcmm/links/"):
            continue
        link_path = path.rsplit("/", 2)[0]
        geo = obj["geometries"][0]
        if geo["type"] == "BoxGeometry":
            half = 0.5 * np.array([geo["width"], geo["height"], geo["depth"]])
        else:  # a cylinder along its y
            r = max(geo["radiusTop"], geo["radiusBottom"])
            half = np.array([r, 0.5 * geo["height"], r])
        corners = np.array([[sx, sy, sz, 1.0] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
        corners[:, :3] *= half
        local = (corners @ transforms[path].T)[:, :2]
        frames, pos = clips[link_path]["position"]
        quat = clips[link_path]["quaternion"][1]
        for p, (_, _, z, w) in zip(pos, quat):
            th = 2 * math.atan2(z, w)
            R = np.array([[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]])
            world = local @ R.T + np.array(p[:2])
            lo, hi = np.minimum(lo, world.min(axis=0)), np.maximum(hi, world.max(axis=0))
            assert (world[:, 0] >= cam["left"]).all() and (world[:, 0] <= cam["right"]).all(), (path, frames)
            assert (world[:, 1] >= cam["bottom"]).all() and (world[:, 1] <= cam["top"]).all(), (path, frames)
    fill = max((hi[0] - lo[0]) / (cam["right"] - cam["left"]), (hi[1] - lo[1]) / (cam["top"] - cam["bottom"]))
    assert fill > 0.7, f"the mechanism fills only {fill:.0%} of the view"


def test_scale_bar_has_a_round_length_inside_the_view(page):
    commands = decode_commands(page.read_text(encoding="utf-8"))
    cam, objects, transforms = _camera(commands), _objects(commands), _transforms(commands)
    bar = objects["/meshcat/pcmm/scale/bar"]["geometries"][0]["width"]
    mantissa = bar / 10 ** math.floor(math.log10(bar))
    assert min(abs(mantissa - m) for m in (1, 2, 5)) < 1e-9, bar
    assert 0.1 <= bar / (cam["right"] - cam["left"]) <= 0.25 + 1e-12
    label = f"{bar:g} m"
    assert _texture_png(objects["/meshcat/pcmm/scale/label"]) == replay._label_png(label, **replay.SCALE_LABEL)[0]
    x = transforms["/meshcat/pcmm/scale/bar"][0, 3]
    assert cam["left"] < x - bar / 2 and x + bar / 2 < cam["right"]


def test_merge_and_release_are_shown(runs, tmp_path):
    traj = runs[0]
    release = {"t": 0.3, "name": "O3 latches", "kind": "mobile", "transition": "release", "from": "config2",
               "to": "config1", "merge": False, "impact": False, "contact_point": [0.2, 0.1],
               "impulse": {"normal": 0.0, "vector": [0.0, 0.0]}}
    with_release = dataclasses.replace(traj, events=[*traj.events, release])
    html = replay.html_page(with_release, fps=FPS)
    kinds = [m[0] for m in _MARKER.findall(html)]
    assert kinds == ["merge", "release"]
    clips = clips_of(decode_commands(html))
    for i, t in enumerate((traj.events[0]["t"], 0.3)):  # each event's plate, from its own frame on
        vis = clips[f"/meshcat/pcmm/plates/{i}/fade0"]["visible"]
        key = t * FPS
        assert value_at(vis, key) is True and value_at(vis, key - 1e-6) is False
        n = len(replay._FADE)  # it fades in n steps over PLATE_S: step j shows in the j-th n-th of it
        for j in range(n):
            mid = t + (j + 0.5) * sk.PLATE_S / n
            if mid < T_END:
                steps = [value_at(clips[f"/meshcat/pcmm/plates/{i}/fade{k}"]["visible"], mid * FPS) for k in range(n)]
                assert steps == [k == j for k in range(n)], (i, j, steps)
    assert "/meshcat/pcmm/arrows/1" not in clips, "a release carries no impulse arrow"


def test_two_runs_overlaid_each_in_its_own_colour(runs):
    html = replay.html_page(runs[0], fps=FPS, others=[runs[1]])
    commands = decode_commands(html)
    clips = clips_of(commands)
    for link in runs[0].links:
        assert f"/meshcat/pcmm/links/{link}" in clips and f"/meshcat/pcmm/run2/links/{link}" in clips
    first = _link_colours(commands)
    second = _link_colours(commands, "/meshcat/pcmm/run2/links/")
    run_colours = [replay._rgba_int(c) for c in replay.RUN_COLOURS[:2]]
    assert {c for link in ("link1", "link2", "link3") for c in first[link]} == {run_colours[0]}
    assert {c for link in ("link1", "link2", "link3") for c in second[link]} == {run_colours[1]}
    rows = re.findall(r'<div class="pcmm-row" data-run="(\d)">', html)
    assert rows == ["0", "1"]
    markers = _MARKER.findall(html)
    assert [m[1] for m in markers] == ["0"] * len(runs[0].events) + ["1"] * len(runs[1].events)
    # without impact the latch still merges the links (no impulse, so no arrow in that run)
    assert [m[0] for m in markers if m[1] == "1"] == ["merge"] and not runs[1].events[0]["impact"]
    assert "/meshcat/pcmm/arrows/0" in clips and not [p for p in clips if p.startswith("/meshcat/pcmm/run2/arrows")]
    data = page_data(html)
    assert [r["impact"] for r in data["runs"]] == [True, False]


def test_cli_replays_two_files_overlaid(runs, tmp_path, capsys):
    from pcmm.cli import main
    a, b = runs[0].save(tmp_path / "a.npz"), runs[1].save(tmp_path / "b.npz")
    out = tmp_path / "both.html"
    assert main(["replay", str(a), str(b), "--html", str(out)]) == 0
    html = out.read_text(encoding="utf-8")
    assert re.findall(r'<div class="pcmm-row" data-run="(\d)">', html) == ["0", "1"]
    assert "/meshcat/pcmm/run2/links/link1" in clips_of(decode_commands(html))
    assert main(["replay", str(a), str(b), "--html", str(out)]) == 2  # exists: needs --force
    assert f"{out}: exists; pass --force" in capsys.readouterr().err


# ---- the trajectory file alone ---------------------------------------------------------------
def test_replay_after_the_scene_and_urdfs_are_deleted(tmp_path, capsys):
    import shutil
    from pcmm.cli import main
    from scene_files import copy_example1
    scene = copy_example1(tmp_path)
    npz = tmp_path / "run.npz"
    assert main(["run", str(scene), "--t-end", "0.3", "--out", str(npz), "--quiet"]) == 0
    shutil.rmtree(tmp_path / "urdf")
    scene.unlink()
    out = tmp_path / "replay.html"
    assert main(["replay", str(npz), "--html", str(out)]) == 0
    commands = decode_commands(out.read_text(encoding="utf-8"))
    objects = _objects(commands)
    for config in ("config1", "config2"):
        for link in ("link1", "link2", "link3"):
            assert f"/meshcat/pcmm/links/{link}/{config}/visual0" in objects
    assert len(_MARKER.findall(out.read_text(encoding="utf-8"))) == 1


def _as_first_format(src: Path, dst: Path, scene: str):
    """``src`` rewritten as pcmm-trajectory-1 wrote it: no views."""
    with np.load(src, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    header = json.loads(str(arrays["header"]))
    header.pop("views")
    header.update(format="pcmm-trajectory-1", scene=scene)
    arrays["header"] = np.array(json.dumps(header))
    np.savez_compressed(dst, **arrays)


def test_first_format_files_load_and_replay_or_say_why_not(runs, tmp_path):
    traj = runs[0]
    new = traj.save(tmp_path / "new.npz")
    old = tmp_path / "old.npz"
    _as_first_format(new, old, str(SCENE))
    loaded = pcmm.Trajectory.load(old)
    # the views come back from the scene file while it exists: the same URDF text
    assert loaded.views["configurations"] == pcmm.Trajectory.load(new).views["configurations"]
    assert set(loaded.views["forces"]) == {"tau1", "tau2", "tau3"}
    assert "/meshcat/pcmm/links/link1/config2/visual0" in _objects(decode_commands(replay.html_page(loaded)))
    # without the scene: the file still loads (figures, CSV), and the replay says what to do
    gone = tmp_path / "gone.npz"
    _as_first_format(new, gone, str(tmp_path / "deleted.toml"))
    orphan = pcmm.Trajectory.load(gone)
    assert np.array_equal(orphan.t, traj.t)
    with pytest.raises(pcmm.UsageError, match=r"gone\.npz: .*earlier pcmm version.*deleted\.toml.*pcmm run"):
        replay.html_page(orphan)


def test_an_unknown_format_is_named(runs, tmp_path):
    new = runs[0].save(tmp_path / "new.npz")
    with np.load(new, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    header = json.loads(str(arrays["header"]))
    header["format"] = "pcmm-trajectory-9"
    arrays["header"] = np.array(json.dumps(header))
    np.savez_compressed(tmp_path / "future.npz", **arrays)
    with pytest.raises(pcmm.UsageError, match=r"future\.npz: .*'pcmm-trajectory-9'.*newer pcmm"):
        pcmm.Trajectory.load(tmp_path / "future.npz")


def _imports(module: Path) -> set[str]:
    """The pcmm modules ``module`` imports (relative imports, at any depth in the file)."""
    import ast
    out = set()
    for node in ast.walk(ast.parse(module.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.level == 1:
            if node.module:
                out.add(node.module.split(".")[0])
            else:
                out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("pcmm."):
            out.add(node.module.split(".")[1])
    return out


def test_replay_and_plots_import_nothing_of_the_scene_or_the_models():
    seen, todo = set(), ["replay", "plots"]
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        todo += sorted(_imports(ROOT / "pcmm" / f"{name}.py"))
    assert seen <= {"replay", "replay_page", "plots", "trajectory", "errors", "outputs", "signals"}, seen


def _meshcat_children():
    import psutil
    out = []
    for p in psutil.Process().children(recursive=True):
        try:
            if p.status() != psutil.STATUS_ZOMBIE and "meshcat.servers.zmqserver" in " ".join(p.cmdline()):
                out.append(p.pid)
        except psutil.NoSuchProcess:
            pass
    return out


def _spy_servers(monkeypatch):
    started = []
    real = replay._start_server

    def spy():
        proc, url = real()
        started.append(proc)
        return proc, url
    monkeypatch.setattr(replay, "_start_server", spy)
    return started


def _assert_stopped(started):
    assert started, "serve() started no meshcat server"
    for proc in started:
        assert proc.poll() is not None, f"meshcat server {proc.pid} still running"
        with pytest.raises(ProcessLookupError):  # ended and reaped: no such process
            os.kill(proc.pid, 0)
    try:
        import psutil  # noqa: F401
    except ImportError:
        return
    assert _meshcat_children() == [], "a meshcat server process was left behind"


def test_serve_no_wait_leaves_no_server(runs, monkeypatch, capsys):
    started = _spy_servers(monkeypatch)
    monkeypatch.setenv(replay.NO_WAIT_ENV, "1")
    assert replay.serve(runs[0], fps=30) is None
    _assert_stopped(started)
    assert "http://127.0.0.1:" in capsys.readouterr().out


def test_serve_ctrl_c_stops_the_server(runs, monkeypatch):
    started = _spy_servers(monkeypatch)
    monkeypatch.delenv(replay.NO_WAIT_ENV, raising=False)

    def interrupt(_):
        raise KeyboardInterrupt
    monkeypatch.setattr(replay, "time", types.SimpleNamespace(sleep=interrupt))
    replay.serve(runs[0], fps=30)  # Ctrl-C ends the replay normally
    _assert_stopped(started)


def test_serve_serves_the_replay_page(runs, monkeypatch, capsys):
    """While serving, the printed URL returns the same page as --html (readout, timeline, scene)."""
    import urllib.request
    started = _spy_servers(monkeypatch)
    monkeypatch.delenv(replay.NO_WAIT_ENV, raising=False)
    got = {}

    def fetch_then_interrupt(_):
        url = re.search(r"open (http://127\.0\.0\.1:\d+/) in a browser", capsys.readouterr().out).group(1)
        with urllib.request.urlopen(url, timeout=10) as r:
            got["page"] = r.read().decode("utf-8")
        raise KeyboardInterrupt
    monkeypatch.setattr(replay, "time", types.SimpleNamespace(sleep=fetch_then_interrupt))
    replay.serve(runs[0], fps=FPS)
    _assert_stopped(started)
    page = got["page"]
    assert len(_MARKER.findall(page)) == len(runs[0].events)
    assert '<span id="pcmm-time">' in page
    served = clips_of(decode_commands(page))
    offline = clips_of(decode_commands(replay.html_page(runs[0], fps=FPS)))
    assert served.keys() == offline.keys()
    assert served["/meshcat/pcmm/links/link3"]["position"] == offline["/meshcat/pcmm/links/link3"]["position"]


def test_serve_error_stops_the_server(runs, monkeypatch):
    started = _spy_servers(monkeypatch)
    broken = pcmm.Trajectory(scene=str(SCENE.parent / "missing.toml"), scene_name="x", impact=True,
                             segments=runs[0].segments, events=runs[0].events)
    with pytest.raises(pcmm.UsageError, match="missing.toml"):
        replay.serve(broken)
    _assert_stopped(started)


# ---- real browser --------------------------------------------------------------------------
@pytest.fixture(scope="module")
def chromium(tmp_path_factory):
    """One headless Chromium for this module's browser tests (per xdist worker), each page opened
    in a fresh browser context of it: a launch costs seconds of CPU (its software WebGL), a page a
    fraction.  Closed once the module's tests are done (not at the session's end): even parked on
    about:blank, the browser takes about 0.06 of a core (tests/headless.py) while the rest of the
    suite runs."""
    browser = headless.Chromium(tmp_path_factory.mktemp("chromium"))
    yield browser
    browser.close()


def _screenshots(chromium, page: Path, times, tmp_path, dom_at=None, size=(800, 600)):
    """Images (H, W, 3) of the page at each time: opened at the first (``page.html#t=<seconds>``),
    then taken to each other by the page's own seek (what a click on the timeline does; the same
    pixels as a fresh load at that time: checked on the cycle's page, 0 pixels differ); plus the
    DOM at ``dom_at`` (from the screenshot's page at that time, if there is one)."""
    from PIL import Image
    steps = [(None if i == 0 else f"window.pcmm.seek({t!r})", tmp_path / f"t{i}.png") for i, t in enumerate(times)]
    with_dom = times.index(dom_at) if dom_at in times else None
    dom = chromium.shots(f"{page.as_uri()}#t={times[0]!r}", size, steps, dom_step=with_dom)
    images = []
    for _, shot in steps:
        assert shot.exists(), chromium.log
        images.append(np.asarray(Image.open(shot).convert("RGB")).astype(int))
    if dom_at is not None and with_dom is None:
        dom = chromium.open(f"{page.as_uri()}#t={dom_at!r}", dom=True)
    return images, dom


def _pixel_map(view, w, h):
    """World (x, y) -> pixel (column, row) in the view above the bar: the page centres the fitted
    window and widens its short side to the canvas's aspect."""
    bw, bh = view.right - view.left, view.top - view.bottom
    cx, cy = 0.5 * (view.left + view.right), 0.5 * (view.top + view.bottom)
    if bw / bh < w / h:
        bw = bh * w / h
    else:
        bh = bw * h / w

    def pixel(x, y):
        return int(round((x - cx + bw / 2) / bw * w)), int(round((cy + bh / 2 - y) / bh * h))
    return pixel


needs_chromium = pytest.mark.skipif(not headless.CHROMIUM.exists(), reason="needs Debian's chromium (/usr/bin/chromium)")


@pytest.mark.browser
@needs_chromium
def test_browser_renders_the_mechanism_at_two_times(chromium, runs, page, tmp_path):
    traj = runs[0]
    times = (0.05, 0.35)  # before and after the latch (t = 0.167 s)
    images, _ = _screenshots(chromium, page, times, tmp_path)
    h, w, _ = images[0].shape
    assert (w, h) == (800, 600)
    view = replay.view_box(traj, replay.run_visuals(traj), fps=FPS)
    pixel = _pixel_map(view, w, h - replay.BAR_PX)

    for img, t in zip(images, times):
        background = img[h - replay.BAR_PX - 3, 2]
        assert (background >= 250).all(), "white background expected"
        poses, _ = replay.resample(traj, np.array([t]))
        # the region the links span at time t (their frame origins and tips), in pixels
        pts = []
        for link, p in poses.items():
            x, y, th = p[0]
            pts.append(pixel(x, y))
            pts.append(pixel(x + 0.1 * math.cos(th), y + 0.1 * math.sin(th)))
        (x0, y0), (x1, y1) = np.min(pts, axis=0) - 12, np.max(pts, axis=0) + 12
        region = img[max(y0, 0):y1, max(x0, 0):x1]
        drawn = np.any(np.abs(region - background) > 30, axis=2)
        assert int(drawn.sum()) > 300, f"t = {t}: the mechanism is not drawn ({int(drawn.sum())} pixels)"
        # each moving link's bar: its midpoint pixel is coloured (not background)
        for link in ("link1", "link2"):
            x, y, th = poses[link][0]
            px, py = pixel(x + 0.06 * math.cos(th), y + 0.06 * math.sin(th))
            patch = img[py - 3:py + 4, px - 3:px + 4]
            coloured = bool(np.any(np.abs(patch - background) > 30))
            assert coloured, f"t = {t}: {link} is not drawn at pixel ({px}, {py})"
    changed = np.any(np.abs(images[0][:h - replay.BAR_PX] - images[1][:h - replay.BAR_PX]) > 30, axis=2)
    assert int(changed.sum()) > 300, f"the two times must look different ({int(changed.sum())} pixels differ)"


def _red(img):
    return (img[..., 0] > 150) & (img[..., 1] < 90) & (img[..., 2] < 90)


@pytest.mark.browser
@needs_chromium
def test_browser_shows_the_impulse_arrow_and_the_time_at_the_impact(chromium, runs, page, tmp_path):
    """Opened at the impact's exact instant, the page shows the impulse arrow (red pixels along
    it, none there 30 ms before) and the time readout says that instant."""
    traj = runs[0]
    ev = _first_impact(traj)
    t = ev["t"]
    images, dom = _screenshots(chromium, page, (t, t - 0.03), tmp_path, dom_at=t)
    at, before = images
    h, w, _ = at.shape
    view = replay.view_box(traj, replay.run_visuals(traj), fps=FPS)
    pixel = _pixel_map(view, w, h - replay.BAR_PX)
    p0 = np.array(ev["contact_point"])
    tip = p0 + view.arrow_scale * np.array(ev["impulse"]["vector"])
    along = [pixel(*(p0 + s * (tip - p0))) for s in np.linspace(0.3, 0.9, 13)]  # clear of the contact marker
    red_at = sum(bool(_red(at[y - 2:y + 3, x - 2:x + 3]).any()) for x, y in along)
    red_before = sum(bool(_red(before[y - 2:y + 3, x - 2:x + 3]).any()) for x, y in along)
    assert red_at >= 12, f"the impulse arrow is not drawn at the impact ({red_at} of 13 points red)"
    assert red_before == 0, f"an arrow is drawn 30 ms before the impact ({red_before} points red)"
    # the label plate right of the tip carries dark red text
    tx, ty = pixel(*tip)
    plate = at[ty - 25:ty + 25, tx:tx + 160]
    assert int(((plate[..., 0] > 100) & (plate[..., 1] < 60)).sum()) > 40, "no impulse label beside the arrow"
    # the time readout: the DOM says the instant, and the readout's pixels differ from 30 ms before
    m = re.search(r'<span id="pcmm-time">([^<]*)</span>', dom)
    assert m and m.group(1) == f"t = {t:.6f} s", (m and m.group(1), dom[-500:])
    said = f"last event: {sk.plate_text(ev)}: "  # what it was, in words ("latch: impact + merge")
    assert said + "&#x27;" in dom or said + "'" in dom, said
    # the link angles the readout gives are the run's own at the event (the segment that starts there)
    angles = re.search(r'<div id="pcmm-angles">([^<]*)</div>', dom).group(1)
    seg = next(s for s in traj.segments if s.t[0] == t)
    for j, link in enumerate(seg.links):
        if link != "frame":
            assert f"{link} {seg.theta[0, j]:.4f}" in angles, (link, angles)
    bar = slice(h - replay.BAR_PX, h - replay.BAR_PX + 26)
    readout_at, readout_before = at[bar, :160], before[bar, :160]
    assert int((readout_at.sum(axis=2) < 200).sum()) > 100, "no dark text in the time readout"
    assert int(np.any(np.abs(readout_at - readout_before) > 60, axis=2).sum()) > 20, "the readout does not change"


# ---- the engineer's drawing, in the browser --------------------------------------------------
CYCLE = ROOT / "examples" / "three_bar_cycle.toml"
CYCLE_FPS = 30


@pytest.fixture(scope="module")
def cycle_page(tmp_path_factory):
    """Example 4 to 2.3 s: O3's and O2's pins struck, O2 locked, folded, O2's release at 1.199 s."""
    traj = pcmm.simulate(pcmm.load_scene(CYCLE), pcmm.RunOptions(t_end=2.3))
    path = tmp_path_factory.mktemp("cycle") / "cycle.html"
    replay.write_html(traj, path, fps=CYCLE_FPS)
    return traj, path


def _dark(img):
    return img.sum(axis=2) < 180


@pytest.mark.slow  # the cycle's run and page, six screenshots
@pytest.mark.browser
@needs_chromium
def test_browser_draws_pivots_locks_arcs_and_plates_where_and_when_they_are(chromium, cycle_page, tmp_path):
    traj, page = cycle_page
    first = next(e for e in traj.events if e.get("impact"))
    lock = next(e for e in traj.events if e.get("merge") and e["to"] == "O2_locked")  # O2 locks
    release = next(e for e in traj.events if e["transition"] == "release")
    t_open, t_locked = 0.5 * first["t"], lock["t"] + 0.5 / CYCLE_FPS
    times = (t_open, t_locked, first["t"], first["t"] - 0.004, release["t"] + 0.1, release["t"] + 1.0)
    images, _ = _screenshots(chromium, page, times, tmp_path, size=(1200, 600))  # wide: the readout keeps to one line
    h, w, _ = images[0].shape
    view = replay.view_box(traj, replay.run_visuals(traj), fps=CYCLE_FPS)
    pixel = _pixel_map(view, w, h - replay.BAR_PX)
    s_px = pixel(sk.scale(traj), 0.0)[0] - pixel(0.0, 0.0)[0]  # the symbols' size in pixels
    assert s_px >= 8

    def ring(img, centre, radius, test):
        cx, cy = pixel(*centre)
        pts = [(int(round(cx + radius * s_px * math.cos(a))), int(round(cy - radius * s_px * math.sin(a))))
               for a in np.radians(np.arange(70, 290, 10))]
        return sum(bool(test(img[y - 1:y + 2, x - 1:x + 2]).any()) for x, y in pts) / len(pts)

    def at(img, xy, r=1):
        x, y = pixel(*xy)
        return img[y - r:y + r + 1, x - r:x + r + 1]

    # the fixed pivot O1 at its world position (0, 0) at every instant: its pin ring is drawn there
    for img in images:
        assert ring(img, (0.0, 0.0), 0.35, _dark) >= 0.8
    # O2 (link2's origin): an open circle (white centre) before the lock, a filled disk while it holds
    o2_open = sk.pose_at(traj, "link2", t_open)[:2]
    o2_locked = sk.pose_at(traj, "link2", t_locked)[:2]
    assert not _dark(at(images[0], o2_open)).any(), "a free joint must be an open circle"
    assert ring(images[0], o2_open, 0.35, _dark) >= 0.6
    assert _dark(at(images[1], o2_locked)).all(), "the locked O2 must be a filled disk"
    # the moment arc about O3 at the first impact (a joint stop at O3), none 4 ms before
    o3 = sk.pose_at(traj, "link3", first["t"])[:2]
    red = lambda p: (p[..., 0] > 140) & (p[..., 1] < 80) & (p[..., 2] < 80)  # noqa: E731
    assert ring(images[2], o3, 1.3, red) >= 0.6, "no moment arc at the joint-stop impact"
    assert ring(images[3], sk.pose_at(traj, "link3", first["t"] - 0.004)[:2], 1.3, red) <= 0.1
    # the release's plate (green) 0.1 s after it, and no plate at all 1 s after it
    # (the plate's ink, replay.PLATE_COLOURS["release"] = (20, 120, 40); link 3's green has more red)
    green = lambda img: (img[..., 0] < 70) & (img[..., 1] > 85) & (img[..., 2] < 85)  # noqa: E731
    plate = next(m for m in sk.event_marks(traj) if m.kind == "plate" and m.text == "release (tensile hold)")
    s_m, lh = sk.scale(traj), replay.PLATE_H * view.label_h

    def plate_region(img, t):  # where the plate hangs at t: right of and above its point on the body
        x, y = sk.to_world(sk.pose_at(traj, plate.link, t), plate.xy)  # it rides on its body
        (c0, r0), (c1, r1) = pixel(x + 0.5 * s_m, y + 0.8 * s_m + 1.3 * lh), pixel(x + 0.8 * s_m + 12 * lh, y + 0.5 * s_m)
        return img[max(r0, 0):r1, max(c0, 0):c1]
    assert plate.window[0] == release["t"]
    assert int(green(plate_region(images[4], release["t"] + 0.1)).sum()) > 15, "no release plate 0.1 s after it"
    assert int(green(plate_region(images[5], release["t"] + 1.0)).sum()) == 0, "a plate 1 s after its event"
    assert int(green(images[5][:h - replay.BAR_PX - 40]).sum()) == 0, "a plate anywhere 1 s after its event"


@pytest.mark.browser
@needs_chromium
def test_browser_shows_the_second_runs_readout_in_full(chromium, runs, tmp_path):
    """Two runs in a narrow window: each run has its own row, the rows wrap instead of being cut,
    and the view shrinks to leave the bar its height."""
    path = tmp_path / "two.html"
    replay.write_html(runs[0], path, fps=FPS, others=[runs[1]])
    shot = tmp_path / "two.png"
    dom = chromium.open(f"{path.as_uri()}#t=0.3", (520, 600), shot, dom=True)
    from PIL import Image
    img = np.asarray(Image.open(shot).convert("RGB")).astype(int)
    h, w, _ = img.shape
    ev = runs[1].events[0]
    m = re.search(r'<div class="pcmm-run-row" id="pcmm-run-1">(.*?)</div>', dom, re.S)
    text = re.sub(r"<[^>]+>", "", m.group(1)).replace("&#x27;", "'").replace("&gt;", ">")
    assert text.startswith("three_bar (without impact): config2")
    assert text.endswith(f"'{ev['name']}' at t = {ev['t']:.7g} s, config1 → config2"), text
    # the bar (light grey, #f6f6f6) starts higher than one run's bar: it grew to hold the rows
    column = img[:, 3]
    grey = np.all(np.abs(column - 246) <= 3, axis=1)
    top = int(np.argmax(grey))
    assert grey[top:].mean() > 0.6 and h - top > replay.BAR_PX + 15, (h - top)
    # text reaches down into the bar's lower rows, and nothing is cut at the right edge
    rows_with_text = [y for y in range(top, h) if _dark(img[y:y + 1, 10:w - 10]).any()]
    assert rows_with_text and rows_with_text[-1] < h - 3


# ---- layouts and views ------------------------------------------------------------------------
def test_side_by_side_runs_do_not_overlap_and_the_view_holds_both(runs):
    a, b = runs
    times = replay.frame_times(list(runs), FPS)
    visuals = [replay.run_visuals(r) for r in runs]
    offsets = replay.side_offsets(list(runs), visuals, times, "side")
    pa, pb = (replay.swept_points(r, v, times) + [dx, 0.0] for r, v, dx in zip(runs, visuals, offsets))
    width_a = np.ptp(pa[:, 0])
    assert offsets[0] == 0.0
    assert pb[:, 0].min() - pa[:, 0].max() == pytest.approx(0.15 * max(width_a, np.ptp(pb[:, 0])), rel=1e-9)
    html = replay.html_page(a, fps=FPS, others=[b], layout="side")
    commands = decode_commands(html)
    moved = [c for c in commands if c["type"] == "set_transform" and c["path"] == "/meshcat/pcmm/run2"]
    assert moved and moved[-1]["matrix"][12] == pytest.approx(offsets[1])  # three.js: column-major
    view = page_data(html)["view"]
    assert view["left"] <= pa[:, 0].min() and view["right"] >= pb[:, 0].max()
    assert page_data(html)["layout"] == "side"
    with pytest.raises(pcmm.UsageError, match="--layout 'diagonal'"):
        replay.side_offsets(list(runs), visuals, times, "diagonal")


def test_the_follow_view_holds_the_mechanism_at_every_frame_and_is_tighter_than_the_run(runs):
    traj = runs[0]
    html = replay.html_page(traj, fps=FPS, view="follow")
    data = page_data(html)
    boxes, frames = data["boxes"], data["frames"]
    assert len(boxes) == len(frames)
    poses, _ = replay.resample(traj, np.array(frames))
    for k, (l, r, b, t) in enumerate(boxes):
        for link, p in poses.items():  # every link's frame origin is inside its frame's box
            assert l <= p[k, 0] <= r and b <= p[k, 1] <= t, (k, link)
    run_area = (data["view"]["right"] - data["view"]["left"]) * (data["view"]["top"] - data["view"]["bottom"])
    assert min((r - l) * (t - b) for l, r, b, t in boxes) < 0.9 * run_area
    # the swept envelope: one faint line per moving link
    lines = [c for c in decode_commands(html) if c["type"] == "set_object" and c["path"].startswith("/meshcat/pcmm/envelope/")]
    assert sorted(c["path"].rsplit("/", 1)[1] for c in lines) == ["link1", "link2", "link3"]
    assert page_data(replay.html_page(traj, fps=FPS))["boxes"] is None  # --view run: one box


# ---- a struck point pinned where it lands (issue 24): the rimless wheel's feet ------------------
WHEEL = ROOT / "examples" / "rimless_wheel.toml"
WHEEL_FPS = 30


@pytest.fixture(scope="module")
def wheel_page(tmp_path_factory):
    """The rimless wheel to 4 s: spoke 0 pinned at the start, four strikes (the first at about 0.73 s)."""
    traj = pcmm.simulate(pcmm.load_scene(WHEEL), pcmm.RunOptions(t_end=4.0))
    path = tmp_path_factory.mktemp("wheel") / "wheel.html"
    replay.write_html(traj, path, fps=WHEEL_FPS)
    return traj, path


def _pins(commands, clips):
    """``{node: (x, y)}`` of the page's symbol nodes drawn with the cut-joint sprite, with their
    positions on the frame's node (the translation of their transform)."""
    cut_png = replay.sprite("cut")
    objs, tfs = _objects(commands), _transforms(commands)
    out = {}
    for path, obj in objs.items():
        if "/sym/" in path and _texture_png(obj) == cut_png:
            out[path] = (float(tfs[path][0, 3]), float(tfs[path][1, 3]))
    return out


def test_the_page_keeps_each_picture_once_and_every_symbol_names_its_own(wheel_page):
    """The page's image table holds each distinct picture (a sprite, a label) once, every entry
    is named by a command, and each symbol's node is drawn with its own kind's sprite: the
    wheel's eight symbols per stay share a few sprites, not one copy each."""
    traj, page = wheel_page
    html = page.read_text(encoding="utf-8")
    (table,) = _IMAGES.findall(html)
    images = json.loads(table.replace("<\\/", "</"))
    assert len(images) == len(set(images)) and all(u.startswith("data:image/png;base64,") for u in images)
    commands = decode_commands(html)
    used = [im["url"] for c in commands if c["type"] == "set_object" for im in c["object"].get("images", [])]
    assert set(used) == set(images)
    symbols = {path: _texture_png(obj) for path, obj in _objects(commands).items() if "/sym/" in path}
    drawn = [sym for i, sym in enumerate(sk.symbols(traj)) if sym.kind != "guide"
             and any(p.endswith(f"/sym/{i}") for p in symbols)]
    assert len(drawn) == len(symbols) > len({replay.sprite(s.kind, s.shape) for s in drawn})
    for i, sym in enumerate(sk.symbols(traj)):
        for path, png in symbols.items():
            if path.endswith(f"/sym/{i}"):
                assert png == replay.sprite(sym.kind, sym.shape), path
    assert len(images) < len(used)


def test_the_page_draws_each_pinned_foot_at_its_strike_for_exactly_its_stay(wheel_page):
    """Strike k pins spoke k's tip where it lands: on the slope at x = 2 l sin(pi/N) k = k m (the spokes
    are 1 m, N = 6; the hub rolls one chord a strike), so the page has one pin per stay at (k, 0) on the
    frame, visible from its strike's frame up to (not at) the next strike's frame, and no other."""
    traj, page = wheel_page
    html = page.read_text(encoding="utf-8")
    commands = decode_commands(html)
    clips = clips_of(commands)
    strikes = [e["t"] for e in traj.events if e["transition"] == "pin"]
    assert len(strikes) == 4
    starts = [traj.segments[0].t[0], *strikes]
    pins = _pins(commands, clips)
    assert len(pins) == 5, sorted(pins)
    assert all(p.startswith("/meshcat/pcmm/links/frame/sym/") for p in pins)
    frames = np.array(page_data(html)["frames"])
    fps = clips[next(iter(pins))]["_fps"]
    for k, (path, xy) in enumerate(sorted(pins.items(), key=lambda kv: kv[1][0])):
        assert xy[0] == pytest.approx(2 * math.sin(math.pi / 6) * k, abs=1e-9)
        assert xy[1] == pytest.approx(0.0, abs=1e-9)
        t0, t1 = starts[k], (starts[k + 1] if k + 1 < len(starts) else math.inf)
        shown = np.array([value_at(clips[path]["visible"], fps * (t - frames[0])) for t in frames])
        expected = (frames >= t0) & (frames < t1)
        assert expected.any() and (shown == expected).all(), (k, np.flatnonzero(shown != expected))
    # at each strike's own frame exactly one pin is shown: the new foot's, one chord further on
    for k, t in enumerate(strikes, start=1):
        on = [pins[p] for p in pins if value_at(clips[p]["visible"], fps * (t - frames[0]))]
        assert len(on) == 1 and on[0][0] == pytest.approx(k, abs=1e-9), (t, on)


def _cut_ink(img):
    """The cut joint's purple (sprites.CUT = (123, 63, 181)), also blended into white at its thin
    edges; not the wheel's spokes (77, 77, 153: as much red as green) nor black or grey."""
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    return (r - g > 25) & (b - g > 50) & (b > r)


@pytest.mark.browser
@needs_chromium
def test_browser_draws_the_pinned_foot_while_it_holds_and_not_after(chromium, wheel_page, tmp_path):
    """Screenshots during spoke 0's stay and during spoke 1's: the cut joint's ring (purple) around the
    struck anchor's screen position while that stay lasts, and none at the old anchor after the
    next strike."""
    traj, page = wheel_page
    strike = next(e["t"] for e in traj.events if e["transition"] == "pin")
    times = (0.5 * strike, strike + 0.3)
    images, _ = _screenshots(chromium, page, times, tmp_path, size=(1600, 700))
    h, w, _ = images[0].shape
    view = replay.view_box(traj, replay.run_visuals(traj), fps=WHEEL_FPS)
    pixel = _pixel_map(view, w, h - replay.BAR_PX)
    s_px = pixel(sk.scale(traj), 0.0)[0] - pixel(0.0, 0.0)[0]
    assert s_px >= 6

    def ring(img, centre):  # the cut ring's radius is 0.4 s
        cx, cy = pixel(*centre)
        pts = [(int(round(cx + 0.4 * s_px * math.cos(a))), int(round(cy - 0.4 * s_px * math.sin(a))))
               for a in np.radians(np.arange(0, 360, 15))]
        return sum(bool(_cut_ink(img[y - 1:y + 2, x - 1:x + 2]).any()) for x, y in pts) / len(pts)

    foot0, foot1 = (0.0, 0.0), (1.0, 0.0)
    assert ring(images[0], foot0) >= 0.6, "no pin at spoke 0's anchor during its stay"
    assert ring(images[0], foot1) == 0.0, "a pin at spoke 1's anchor before it strikes"
    assert ring(images[1], foot1) >= 0.6, "no pin at spoke 1's anchor during its stay"
    assert ring(images[1], foot0) == 0.0, "spoke 0's pin is still drawn after the next strike"


def test_the_compass_gaits_page_pins_each_new_stance_foot_where_its_heel_struck(tmp_path):
    """Each heel strike pins the swing foot at the strike's contact point (the event record's, a route
    independent of the drawing's pose lookup); the page shows that pin from the strike's frame until
    the next strike's, the initial stance foot at the origin until the first."""
    traj = pcmm.simulate(pcmm.load_scene(ROOT / "examples" / "compass_gait.toml"), pcmm.RunOptions(t_end=1.6))
    html = replay.html_page(traj, fps=WHEEL_FPS)
    commands = decode_commands(html)
    clips = clips_of(commands)
    strikes = [e for e in traj.events if e["transition"] == "pin"]
    assert len(strikes) == 2
    anchors = [(0.0, 0.0)] + [tuple(e["contact_point"]) for e in strikes]
    starts = [traj.segments[0].t[0]] + [e["t"] for e in strikes] + [math.inf]
    pins = sorted(_pins(commands, clips).items(), key=lambda kv: kv[1][0])
    assert len(pins) == 3
    frames = np.array(page_data(html)["frames"])
    for k, (path, xy) in enumerate(pins):
        assert xy == pytest.approx(anchors[k], abs=1e-9)
        fps = clips[path]["_fps"]
        shown = np.array([value_at(clips[path]["visible"], fps * (t - frames[0])) for t in frames])
        assert (shown == ((frames >= starts[k]) & (frames < starts[k + 1]))).all(), k
