"""Replay: the offline HTML page and the live meshcat server.

Most tests need no browser: they decode the meshcat commands embedded in the
page (msgpack, base64 in ``fetch("data:...")`` calls) and check the one
animation it carries.  The ``browser`` test renders the page in headless
Chromium at two times (``page.html#t=<seconds>``).
"""
from __future__ import annotations

import base64
import math
import os
import re
import subprocess
import types
from pathlib import Path

import numpy as np
import pytest

import pcmm
from pcmm import replay

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "examples" / "three_bar.toml"
FPS = 60
T_END = 0.4
CHROMIUM = Path("/usr/bin/chromium")

try:
    import umsgpack as _msgpack  # meshcat's own dependency

    def _unpack(b):
        return _msgpack.unpackb(b)
except ImportError:  # pragma: no cover
    import msgpack as _msgpack

    def _unpack(b):
        return _msgpack.unpackb(b, raw=False)

_COMMAND = re.compile(r'fetch\("data:application/octet-binary;base64,([A-Za-z0-9+/=]+)"\)')


def decode_commands(html: str) -> list[dict]:
    return [_unpack(base64.b64decode(m)) for m in _COMMAND.findall(html)]


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


def test_one_transform_track_per_link_and_frame_count(runs, clips):
    traj = runs[0]
    duration = float(traj.t[-1] - traj.t[0])
    moving = {p: c for p, c in clips.items() if "position" in c and "/links/" in p}
    assert sorted(moving) == sorted(f"/meshcat/pcmm/links/{link}" for link in traj.links)
    # no other node under links/ moves on its own: the geometry rides on its link's track
    assert not [p for p, c in clips.items() if "quaternion" in c and p not in moving]
    expected = duration * FPS
    for path, c in moving.items():
        frames, _ = c["position"]
        assert c["_fps"] == FPS
        assert abs(len(frames) - expected) <= 1, (path, len(frames), expected)
        assert frames == list(range(len(frames)))
        assert c["quaternion"][0] == frames
        assert math.isclose(frames[-1] / FPS, duration, abs_tol=1.0 / FPS)


def test_link_poses_follow_the_trajectory(runs, clips):
    traj = runs[0]
    last = traj.segments[-1]
    for j, link in enumerate(last.links):
        c = clips[f"/meshcat/pcmm/links/{link}"]
        pos, quat = c["position"][1], c["quaternion"][1]
        first = traj.segments[0]
        assert np.allclose(pos[0][:2], first.xy[0, first.links.index(link)], atol=1e-12)
        assert np.allclose(pos[-1][:2], last.xy[-1, j], atol=1e-9)
        x, y, z, w = quat[-1]
        assert x == 0 and y == 0
        assert math.isclose(math.cos(last.theta[-1, j]), w * w - z * z, abs_tol=1e-9)
        assert math.isclose(math.sin(last.theta[-1, j]), 2 * w * z, abs_tol=1e-9)
        # a frame in the middle: the link frame origin interpolated at k / fps
        k = len(pos) // 2
        seg = next(s for s in reversed(traj.segments) if s.t[0] <= k / FPS)
        i = seg.links.index(link)
        expect = [np.interp(k / FPS, seg.t, seg.xy[:, i, 0]), np.interp(k / FPS, seg.t, seg.xy[:, i, 1])]
        assert np.allclose(pos[k][:2], expect, atol=1e-12)


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


def test_serve_error_stops_the_server(runs, monkeypatch):
    started = _spy_servers(monkeypatch)
    broken = pcmm.Trajectory(scene=str(SCENE.parent / "missing.toml"), scene_name="x", impact=True,
                             segments=runs[0].segments, events=runs[0].events)
    with pytest.raises(pcmm.UsageError, match="missing.toml"):
        replay.serve(broken)
    _assert_stopped(started)


# ---- real browser --------------------------------------------------------------------------
def _screenshot(url: str, out: Path, profile: Path) -> subprocess.Popen:
    profile.mkdir()
    return subprocess.Popen(
        [str(CHROMIUM), "--headless", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
         "--disable-background-networking", "--no-first-run", "--disable-gpu-sandbox",
         f"--user-data-dir={profile}", "--window-size=800,600", "--hide-scrollbars",
         "--virtual-time-budget=3000", f"--screenshot={out}", url],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)


@pytest.mark.browser
@pytest.mark.skipif(not CHROMIUM.exists(), reason="needs Debian's chromium (/usr/bin/chromium)")
def test_browser_renders_the_mechanism_at_two_times(runs, page, tmp_path):
    from PIL import Image
    traj = runs[0]
    times = (0.05, 0.35)  # before and after the latch (t = 0.167 s)
    procs = []
    for i, t in enumerate(times):
        shot = tmp_path / f"t{i}.png"
        procs.append((shot, _screenshot(f"{page.as_uri()}#t={t}", shot, tmp_path / f"profile{i}")))
    images = []
    for shot, proc in procs:
        try:
            _, err = proc.communicate(timeout=45)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()
            pytest.fail("chromium did not finish in 45 s")
        assert shot.exists(), err.decode(errors="replace")[-2000:]
        images.append(np.asarray(Image.open(shot).convert("RGB")).astype(int))
    h, w, _ = images[0].shape
    assert (w, h) == (800, 600)

    scene = pcmm.load_scene(SCENE)
    visuals = {c: replay.read_visuals(scene.configurations[c].urdf) for c in replay.visited(traj)}
    view = replay.view_box(traj, visuals)
    scale = h / (view.top - view.bottom)  # the viewer keeps the vertical extent, widens to the page

    def pixel(x, y):
        return int(round((x - view.left) * scale)), int(round((view.top - y) * scale))

    for img, t in zip(images, times):
        background = img[h - 2, 2]
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
    changed = np.any(np.abs(images[0] - images[1]) > 30, axis=2)
    assert int(changed.sum()) > 300, f"the two times must look different ({int(changed.sum())} pixels differ)"
