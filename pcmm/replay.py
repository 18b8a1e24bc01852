"""Browser replay of a run in meshcat: a live server or one offline HTML page.

The whole run is sent to meshcat as ONE animation (``meshcat.animation``),
resampled to a uniform frame rate (frame ``k`` shows the run at ``t = k / fps``),
so the browser's own play / pause / reset buttons and time scrubber
(Controls, "Animations" folder) replay and scrub it.

Scene tree (under ``/meshcat/pcmm``):

``links/<link>``
    One group per link name, with the run's only transform track for that
    link (position + quaternion from the trajectory's link frame origin ``xy``
    and absolute angle ``theta``).  The same link in different configurations
    shares this node, so its track is continuous across switches.
``links/<link>/<configuration>/visual<i>``
    The link's URDF visuals (``<box>``, ``<cylinder>``, ``<sphere>``) as
    read from that configuration's URDF.  Every configuration the run visits
    is loaded up front; a ``visible`` track on ``links/<link>/<configuration>``
    shows exactly the active configuration's geometry.
``labels/<configuration>``
    A text plate naming the configuration (e.g. "config2"), above the
    mechanism at the top left; only the active configuration's plate is
    visible, so the current configuration is always readable.
``impacts/<i>``
    Red spheres at the events' contact points (``contact_point``), visible
    for about 0.1 s from the first frame at or after each impact (events
    with ``impact`` true).  Impacts closer together than a flash (the
    micro-impacts of a macro-impact) extend the flash of one sphere.

The camera is orthographic, on +z, looking down at the xy plane (x right,
y up) and framing everything the run sweeps.  The grid and axes are hidden
and the background is white.

An HTML page opened with ``#t=<seconds>`` (e.g. ``replay.html#t=0.25``) starts
paused at that time (a small script added to meshcat's page).

Geometry comes from each configuration's URDF, found through the scene file
the trajectory names (``Trajectory.scene``).
"""
from __future__ import annotations

import atexit
import contextlib
import io
import math
import os
import subprocess
import sys
import tempfile
import time
import warnings
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import UsageError
from .trajectory import Trajectory, atomic_write

#: Set to 1 to make :func:`serve` return once the replay is loaded (tests, scripts).
NO_WAIT_ENV = "PCMM_REPLAY_NO_WAIT"
ROOT = "pcmm"
#: How long an impact marker stays visible, s (at least 3 frames).
FLASH_S = 0.1
CAMERA_Z = 10.0
_WHITE = [1.0, 1.0, 1.0]


def _import_meshcat():
    """Import meshcat (a dependency) without its pyzmq deprecation warning."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        import meshcat
        import meshcat.animation
        import meshcat.geometry
        import meshcat.transformations
    return meshcat


# ---- URDF visuals ----------------------------------------------------------------------
@dataclass(frozen=True)
class Visual:
    kind: str  # "box" | "cylinder" | "sphere"
    size: tuple  # box: (x, y, z); cylinder: (radius, length); sphere: (radius,)
    transform: np.ndarray  # 4x4, visual in the link frame (URDF <origin>)
    rgba: tuple

    @property
    def extent(self) -> float:
        """Half the largest dimension: how far the visual can reach past its origin."""
        if self.kind == "box":
            return 0.5 * float(np.linalg.norm(self.size[:2]))
        return float(max(self.size[0], 0.5 * self.size[-1]))


def _floats(text, n, default):
    if text is None:
        return default
    vals = tuple(float(x) for x in text.split())
    if len(vals) != n:
        raise ValueError(text)
    return vals


def _origin(el) -> np.ndarray:
    tf = _import_meshcat().transformations
    o = el.find("origin") if el is not None else None
    xyz = _floats(o.get("xyz") if o is not None else None, 3, (0.0, 0.0, 0.0))
    rpy = _floats(o.get("rpy") if o is not None else None, 3, (0.0, 0.0, 0.0))
    T = tf.euler_matrix(*rpy, axes="sxyz")  # URDF: R = Rz(yaw) Ry(pitch) Rx(roll)
    T[:3, 3] = xyz
    return T


def read_visuals(urdf: str | Path) -> dict[str, list[Visual]]:
    """``{link: [Visual, ...]}`` for every link of ``urdf`` (links without visuals map to [])."""
    urdf = Path(urdf)
    try:
        root = ET.parse(urdf).getroot()
    except (OSError, ET.ParseError) as exc:
        raise UsageError(f"{urdf}: cannot read the URDF for the replay: {exc}") from None
    named = {}
    for m in root.findall("material"):
        c = m.find("color")
        if c is not None and m.get("name"):
            named[m.get("name")] = _floats(c.get("rgba"), 4, (0.7, 0.7, 0.7, 1.0))
    out: dict[str, list[Visual]] = {}
    for link in root.findall("link"):
        name = link.get("name")
        vis: list[Visual] = []
        for v in link.findall("visual"):
            try:
                T = _origin(v)
                g = v.find("geometry")
                rgba = (0.7, 0.7, 0.7, 1.0)
                m = v.find("material")
                if m is not None:
                    c = m.find("color")
                    if c is not None:
                        rgba = _floats(c.get("rgba"), 4, rgba)
                    elif m.get("name") in named:
                        rgba = named[m.get("name")]
                shape = g[0] if g is not None and len(g) else None
                if shape is None:
                    continue
                if shape.tag == "box":
                    vis.append(Visual("box", _floats(shape.get("size"), 3, None), T, rgba))
                elif shape.tag == "cylinder":
                    vis.append(Visual("cylinder", (float(shape.get("radius")), float(shape.get("length"))),
                                      T, rgba))
                elif shape.tag == "sphere":
                    vis.append(Visual("sphere", (float(shape.get("radius")),), T, rgba))
                else:
                    print(f"pcmm: replay: {urdf}: link '{name}': <{shape.tag}> visuals are not shown "
                          "(box, cylinder and sphere are)", file=sys.stderr)
            except (TypeError, ValueError):
                raise UsageError(f"{urdf}: link '{name}': a <visual> has a malformed number") from None
        out[name] = vis
    return out


def _urdfs(traj: Trajectory) -> dict[str, Path]:
    """Each visited configuration's URDF, from the scene file named in the trajectory."""
    from .scene import load_scene
    path = Path(traj.scene)
    if not path.is_file():
        raise UsageError(f"{traj.scene}: the scene file of this run is not found (from {Path.cwd()}); the "
                         "replay reads each configuration's URDF through it: run pcmm from the folder "
                         "the run was made in")
    scene = load_scene(path)
    out = {}
    for name in visited(traj):
        if name not in scene.configurations:
            raise UsageError(f"{path}: has no configuration '{name}', which the trajectory visits")
        out[name] = Path(scene.configurations[name].urdf)
    return out


def visited(traj: Trajectory) -> list[str]:
    return list(dict.fromkeys(s.configuration for s in traj.segments))


# ---- resampling --------------------------------------------------------------------------
def frame_times(traj: Trajectory, fps: float) -> np.ndarray:
    """Uniform frame times ``k / fps`` (offset by the run's start), ``round(duration * fps) + 1`` frames."""
    if not traj.segments:
        raise UsageError("the trajectory is empty: nothing to replay")
    if not (fps > 0 and math.isfinite(fps)):
        raise UsageError(f"fps = {fps!r}: must be a finite number > 0")
    t0, t1 = float(traj.segments[0].t[0]), float(traj.segments[-1].t[-1])
    n = max(1, int(round((t1 - t0) * fps)))
    return np.minimum(t0 + np.arange(n + 1) / fps, t1)


def segment_at(traj: Trajectory, times: np.ndarray) -> np.ndarray:
    """Index of the segment active at each time (at a switch instant: the new one)."""
    starts = np.array([s.t[0] for s in traj.segments])
    return np.clip(np.searchsorted(starts, times, side="right") - 1, 0, len(starts) - 1)


def resample(traj: Trajectory, times: np.ndarray) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """``({link: (n, 3) [x, y, theta]}, segment index per frame)`` at ``times``.

    Linear interpolation inside the active segment; a link missing from a
    segment keeps its last pose."""
    seg_idx = segment_at(traj, times)
    poses = {link: np.full((len(times), 3), np.nan) for link in traj.links}
    for i, s in enumerate(traj.segments):
        rows = np.nonzero(seg_idx == i)[0]
        if rows.size == 0:
            continue
        tt = times[rows]
        for j, link in enumerate(s.links):
            poses[link][rows, 0] = np.interp(tt, s.t, s.xy[:, j, 0])
            poses[link][rows, 1] = np.interp(tt, s.t, s.xy[:, j, 1])
            poses[link][rows, 2] = np.interp(tt, s.t, s.theta[:, j])
    for p in poses.values():  # forward, then backward fill
        for k in range(1, len(p)):
            if np.isnan(p[k, 0]):
                p[k] = p[k - 1]
        for k in range(len(p) - 2, -1, -1):
            if np.isnan(p[k, 0]):
                p[k] = p[k + 1]
        np.nan_to_num(p, copy=False)
    return poses, seg_idx


def event_frame(t: float, t0: float, fps: float, nframes: int) -> int:
    """The first frame at or after time ``t``."""
    return int(min(max(math.ceil((t - t0) * fps - 1e-9), 0), nframes - 1))


def impact_flashes(traj: Trajectory, fps: float, nframes: int) -> list[dict]:
    """Marker slots: ``[{"windows": [(first, last, (x, y)), ...]}]`` (frames, inclusive)."""
    t0 = float(traj.segments[0].t[0])
    n_flash = max(3, int(round(FLASH_S * fps)))
    slots: list[dict] = []
    for ev in traj.events:
        if not ev.get("impact", False) or ev.get("contact_point") is None:
            continue
        f = event_frame(float(ev["t"]), t0, fps, nframes)
        p = tuple(float(c) for c in ev["contact_point"][:2])
        last = min(f + n_flash - 1, nframes - 1)
        for slot in slots:  # a repeated impact at the same place extends the running flash
            a, b, q = slot["windows"][-1]
            if b >= f - 1 and math.dist(p, q) < 1e-3:
                slot["windows"][-1] = (a, max(b, last), q)
                break
        else:
            free = [s for s in slots if s["windows"][-1][1] < f - 1]
            slot = free[0] if free else {"windows": []}
            if not free:
                slots.append(slot)
            slot["windows"].append((f, last, p))
    return slots


# ---- layout --------------------------------------------------------------------------------
@dataclass(frozen=True)
class View:
    """The camera's world window: left, top, bottom (the viewer sets right from the page's aspect)."""

    left: float
    right: float  # for a square page; wider pages see more to the right
    top: float
    bottom: float
    label_xy: tuple[float, float]
    label_h: float
    marker_r: float


def view_box(traj: Trajectory, visuals: dict[str, dict[str, list[Visual]]]) -> View:
    pts = np.concatenate([s.xy.reshape(-1, 2) for s in traj.segments])
    reach = max([v.extent + float(np.linalg.norm(v.transform[:2, 3]))
                 for per in visuals.values() for vs in per.values() for v in vs] + [0.0])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    span = max(float(np.max(hi - lo)), 2 * reach, 1e-3)
    margin = reach + 0.05 * span
    lo, hi = lo - margin, hi + margin
    label_h = 0.08 * span
    top = hi[1] + 1.6 * label_h
    width = hi[0] - lo[0]
    height = max(top - lo[1], width)  # fits a square or wider page
    bottom = top - height
    return View(left=float(lo[0]), right=float(lo[0] + height), top=float(top), bottom=float(bottom),
                label_xy=(float(lo[0]), float(top - 0.3 * label_h)), label_h=float(label_h),
                marker_r=float(max(0.015 * span, 1e-4)))


def _label_png(text: str) -> tuple[bytes, float]:
    """A PNG plate with ``text``; returns (bytes, width / height)."""
    from PIL import Image, ImageDraw, ImageFont
    try:
        font = ImageFont.load_default(size=56)
    except TypeError:  # Pillow < 10.1: fixed bitmap font
        font = ImageFont.load_default()
    probe = ImageDraw.Draw(Image.new("RGB", (8, 8)))
    x0, y0, x1, y1 = probe.textbbox((0, 0), text, font=font)
    pad = max(8, (y1 - y0) // 3)
    w, h = x1 - x0 + 2 * pad, y1 - y0 + 2 * pad
    img = Image.new("RGB", (w, h), (255, 244, 204))
    draw = ImageDraw.Draw(img)
    draw.rectangle([0, 0, w - 1, h - 1], outline=(120, 100, 40), width=3)
    draw.text((pad - x0, pad - y0), text, fill=(20, 20, 20), font=font)
    buf = io.BytesIO()
    img.save(buf, format="PNG")
    return buf.getvalue(), w / h


# ---- meshcat --------------------------------------------------------------------------------
def _start_server():
    """Start meshcat's server as meshcat.Visualizer() does, but never leave it behind
    if the start itself is interrupted.  Returns (process, zmq_url)."""
    meshcat = _import_meshcat()
    env = dict(os.environ)
    env["PYTHONPATH"] = os.path.dirname(os.path.dirname(os.path.abspath(meshcat.__file__)))
    err = tempfile.TemporaryFile()
    proc = subprocess.Popen([sys.executable, "-u", "-m", "meshcat.servers.zmqserver"],
                            stdout=subprocess.PIPE, stderr=err, stdin=subprocess.DEVNULL, env=env,
                            start_new_session=True)
    atexit.register(_stop, proc)  # a last resort if the process exits without the finally
    try:
        line = ""
        while not line.startswith("zmq_url="):
            raw = proc.stdout.readline()
            if not raw and proc.poll() is not None:
                err.seek(0)
                raise UsageError("the meshcat server did not start: "
                                 + err.read().decode("utf-8", "replace").strip()[-2000:])
            line = raw.decode("utf-8").strip()
        return proc, line[len("zmq_url="):]
    except BaseException:
        _stop(proc)
        raise
    finally:
        err.close()


def _stop(proc) -> None:
    if proc is None:
        return
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    if proc.stdout is not None and not proc.stdout.closed:
        proc.stdout.close()


@contextlib.contextmanager
def _meshcat():
    """A meshcat Visualizer on its own server; the server is always stopped on exit
    (meshcat 0.3.2's Visualizer.close() raises, so it is not used)."""
    meshcat = _import_meshcat()
    proc, zmq_url = _start_server()
    vis = None
    try:
        with contextlib.redirect_stdout(io.StringIO()):  # meshcat prints its URL itself
            vis = meshcat.Visualizer(zmq_url=zmq_url)
        vis.window.server_proc = proc
        yield vis
    finally:
        if vis is not None:
            with contextlib.suppress(Exception):
                vis.window.zmq_socket.close(linger=0)
        _stop(proc)


def _rgba_int(rgba) -> int:
    r, g, b = (int(round(255 * min(max(c, 0.0), 1.0))) for c in rgba[:3])
    return (r << 16) | (g << 8) | b


def _geometry(v: Visual):
    g = _import_meshcat().geometry
    if v.kind == "box":
        return g.Box(list(v.size)), v.transform
    if v.kind == "sphere":
        return g.Sphere(v.size[0]), v.transform
    rot = np.eye(4)  # three.js cylinders lie along y, URDF ones along z
    rot[1:3, 1:3] = [[0.0, -1.0], [1.0, 0.0]]
    return g.Cylinder(v.size[1], v.size[0]), v.transform @ rot


def _send_scene(vis, traj: Trajectory, fps: float):
    """Load every visited configuration's geometry, the labels, markers and camera;
    send the whole run as one animation."""
    mc = _import_meshcat()
    g = mc.geometry
    Animation, AnimationClip, AnimationTrack = (mc.animation.Animation, mc.animation.AnimationClip,
                                                mc.animation.AnimationTrack)

    urdfs = _urdfs(traj)
    visuals = {c: read_visuals(p) for c, p in urdfs.items()}
    view = view_box(traj, visuals)
    times = frame_times(traj, fps)
    nframes = len(times)
    poses, seg_idx = resample(traj, times)
    frame_config = [traj.segments[i].configuration for i in seg_idx]
    base = vis[ROOT]

    # camera: orthographic, on +z, looking down; x right, y up
    class TopCamera(g.OrthographicCamera):
        def lower(self):
            data = super().lower()
            m = np.eye(4)
            m[2, 3] = CAMERA_Z
            data["object"]["matrix"] = [float(x) for x in m.T.flatten()]  # three.js: column-major
            return data
    vis["/Cameras/default"].set_transform(np.eye(4))
    vis["/Cameras/default/rotated"].set_transform(np.eye(4))
    vis["/Cameras/default/rotated"].set_object(
        TopCamera(view.left, view.right, view.top, view.bottom, 0.01, 10 * CAMERA_Z))
    vis["/Background"].set_property("top_color", _WHITE)
    vis["/Background"].set_property("bottom_color", _WHITE)
    vis["/Grid"].set_property("visible", False)
    vis["/Axes"].set_property("visible", False)

    for config, per_link in visuals.items():
        for link, vs in per_link.items():
            if link not in poses:
                print(f"pcmm: replay: link '{link}' of {urdfs[config]} is not in the trajectory; "
                      "its visuals stay at the origin", file=sys.stderr)
            for i, v in enumerate(vs):
                geom, T = _geometry(v)
                node = base[f"links/{link}/{config}/visual{i}"]
                node.set_object(geom, g.MeshPhongMaterial(color=_rgba_int(v.rgba), opacity=float(v.rgba[3])))
                node.set_transform(T)
    for config in visuals:
        png, aspect = _label_png(config)
        tex = g.ImageTexture(image=g.PngImage(png))
        node = base[f"labels/{config}"]
        node.set_object(g.Box([view.label_h * aspect, view.label_h, 1e-4]),
                        g.MeshBasicMaterial(map=tex, color=0xFFFFFF))
        T = np.eye(4)
        T[:3, 3] = [view.label_xy[0] + 0.5 * view.label_h * aspect, view.label_xy[1] - 0.5 * view.label_h, 0.5]
        node.set_transform(T)
    slots = impact_flashes(traj, fps, nframes)
    for i, _ in enumerate(slots):
        base[f"impacts/{i}/marker"].set_object(g.Sphere(view.marker_r),
                                              g.MeshBasicMaterial(color=0xE00000, opacity=0.85))

    anim = Animation(default_framerate=fps)
    path = base.path

    def clip(sub):
        c = AnimationClip(fps=fps)
        anim.clips[path.append(sub)] = c
        return c

    def bool_track(c, key_values):
        """``key_values``: per-frame booleans; keys at frame 0 and at every change."""
        frames, values = [], []
        for k, val in enumerate(key_values):
            if k == 0 or val != values[-1]:
                frames.append(k)
                values.append(bool(val))
        c.tracks["visible"] = AnimationTrack("visible", "boolean", frames, values)

    for link, p in poses.items():
        c = clip(f"links/{link}")
        half = 0.5 * p[:, 2]
        c.tracks["position"] = AnimationTrack(
            "position", "vector3", list(range(nframes)),
            [[float(x), float(y), 0.0] for x, y in p[:, :2]])
        c.tracks["quaternion"] = AnimationTrack(  # three.js order: x, y, z, w
            "quaternion", "quaternion", list(range(nframes)),
            [[0.0, 0.0, float(s), float(w)] for s, w in zip(np.sin(half), np.cos(half))])
    for config, per_link in visuals.items():
        shown = [fc == config for fc in frame_config]
        for link, vs in per_link.items():
            if vs:
                bool_track(clip(f"links/{link}/{config}"), shown)
        bool_track(clip(f"labels/{config}"), shown)
    for i, slot in enumerate(slots):
        c = clip(f"impacts/{i}")
        on = np.zeros(nframes, dtype=bool)
        frames, values = [], []
        for a, b, (x, y) in slot["windows"]:
            on[a:b + 1] = True
            frames += [a, b]
            values += [[x, y, 0.3], [x, y, 0.3]]
        c.tracks["position"] = AnimationTrack("position", "vector3", frames, values)
        bool_track(c, on)
    vis.set_animation(anim, play=True, repetitions=1)
    return {"frames": nframes, "fps": fps, "view": view, "impact_markers": len(slots)}


# ---- public -----------------------------------------------------------------------------------
_HOOK = """
<script>
/* pcmm: open this page with #t=<seconds> (or ?t=<seconds>) to start paused at that time. */
(function () {
  var m = (location.hash + "&" + location.search).match(/[#?&]t=([-+0-9.eE]+)/);
  if (!m) { return; }
  var t = parseFloat(m[1]);
  function go() {
    var a = window.viewer && viewer.animator;
    if (!a || !a.actions.length) { setTimeout(go, 20); return; }
    a.play(); a.pause(); a.seek(t); a.display_progress(t); viewer.set_dirty();
  }
  go();
})();
</script>
"""


def html_page(traj: Trajectory, fps: float = 60) -> str:
    """The self-contained replay page (text)."""
    with _meshcat() as vis:
        _send_scene(vis, traj, fps)
        html = vis.static_html()
    title = f"pcmm replay: {traj.scene_name}{'' if traj.impact else ' (without impact)'}"
    html = html.replace("<title>MeshCat</title>", f"<title>{_escape(title)}</title>", 1)
    i = html.rfind("</body>")
    return html[:i] + _HOOK + html[i:] if i >= 0 else html + _HOOK


def _escape(s: str) -> str:
    return s.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def write_html(traj: Trajectory, path: str | Path, fps: float = 60) -> Path:
    """Write ONE offline HTML page replaying ``traj`` (atomically; overwrites ``path``).

    The page embeds meshcat's viewer and the commands; it needs no server and
    no network.  The meshcat server used to build it is shut down."""
    html = html_page(traj, fps)
    return atomic_write(path, lambda f: f.write(html), force=True)


@contextlib.contextmanager
def _signals_interrupt():
    """Turn SIGTERM / SIGHUP into KeyboardInterrupt while serving, so that the
    server is shut down by the same ``finally`` as on Ctrl-C."""
    import signal
    import threading
    old = {}
    if threading.current_thread() is threading.main_thread():
        def handler(signum, frame):
            raise KeyboardInterrupt(f"signal {signum}")
        for name in ("SIGTERM", "SIGHUP"):
            sig = getattr(signal, name, None)
            if sig is not None:
                with contextlib.suppress(ValueError, OSError):
                    old[sig] = signal.signal(sig, handler)
    try:
        yield
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)


def serve(traj: Trajectory, fps: float = 60) -> None:
    """Replay ``traj`` in meshcat: print the URL, play the run as one animation
    in the browser, block until Ctrl-C (or return at once when the environment
    variable ``PCMM_REPLAY_NO_WAIT=1``).  The meshcat server is always shut down."""
    with _signals_interrupt(), _meshcat() as vis:
        info = _send_scene(vis, traj, fps)
        print(f"pcmm replay: {traj.scene_name}: {info['frames']} frames at {fps:g} fps; open "
              f"{vis.url()} in a browser (Controls > Animations: play, pause, time)", flush=True)
        if os.environ.get(NO_WAIT_ENV, "") not in ("", "0"):
            return
        print("pcmm replay: press Ctrl-C to stop the server", flush=True)
        try:
            while vis.window.server_proc.poll() is None:
                time.sleep(0.5)
            print("pcmm replay: the meshcat server stopped", file=sys.stderr)
        except KeyboardInterrupt:
            print("pcmm replay: stopped", flush=True)


__all__ = ["serve", "write_html", "html_page", "read_visuals", "frame_times", "resample", "view_box",
           "impact_flashes", "event_frame", "NO_WAIT_ENV"]
