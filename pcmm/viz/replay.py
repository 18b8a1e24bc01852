"""Browser replay of a run in meshcat: one offline HTML page, also served live.

The whole run is ONE meshcat animation (``meshcat.animation``).  Its frames
are the uniform times ``t0 + k / fps`` **plus every event's exact instant**
(key times in frames are then fractional), so the state at an impact, a merge
or a release is a frame of the animation, not the next frame after it.

Scene tree (under ``/meshcat/pcmm``; a second run overlaid with ``others``
lives under ``/meshcat/pcmm/run2``, and so on):

``links/<link>``
    One group per link, with the run's only transform track for that link
    (position + quaternion from the link frame origin ``xy`` and absolute
    angle ``theta``), continuous across switches.
``links/<link>/<configuration>/visual<i>``
    The link's URDF visuals (``<box>``, ``<cylinder>``, ``<sphere>``) read
    from the URDF text the trajectory recorded; a ``visible`` track shows
    exactly the active configuration's geometry.  A visual without a
    ``<material>`` gets its link's own colour from :data:`LINK_COLOURS`; with
    several runs, each run is drawn in one colour of :data:`RUN_COLOURS`.
``labels/<configuration>``
    A plate naming the configuration, at the top left of the view.
``impacts/<i>``
    Red spheres at the impacts' contact points, visible for ``FLASH_S`` from
    the impact's own frame.
``arrows/<i>``
    The impulse of impact ``i`` on body b, an arrow from the contact point of
    length ``View.arrow_scale * |P|`` with a plate ``P = ... N·s``; visible
    from the impact's frame until ``FLASH_S`` later or the next impact.
``events/<i>``
    A plate "merge" or "release" at that event's contact point.
``links/<link>/sym/<i>``
    The engineer's symbols of :mod:`pcmm.viz.sketch` (pivots, joints, locks, stops), each with a
    ``visible`` track: shown in its configurations and, for a point pinned where it struck (a cut
    joint anchored at entry: a rimless wheel's foot), as a grounded pin at the strike's anchor from
    the strike's frame up to the next strike's frame, exactly the stay in which it holds.
``scale``
    A scale bar of a round length with its label, at the bottom left.

The camera is orthographic, on +z, looking down (x right, y up), fitted to
everything the run sweeps (every link's visuals at every frame, the impulse
arrows), centred whatever the page's aspect.  Under the view the page shows
the simulated time, each run's configuration and last event, and a timeline
with one marker per event (impact, merge, release, switch) that seeks to the
event's frame on click.  ``page.html#t=<seconds>`` opens paused at that time.

The page is built without a server (the meshcat commands are recorded and
embedded, in order); :func:`serve` also streams them to a live meshcat
server and serves the same page on 127.0.0.1.  Nothing here reads the scene:
the geometry is the trajectory's own record (:attr:`Trajectory.views`).
"""
from __future__ import annotations

import atexit
import contextlib
import functools
import io
import math
import os
import subprocess
import sys
import tempfile
import threading
import time
import warnings
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import UsageError
from ..files import terminal_text
from .page import BAR_PX, IMAGE_REF, RUN_COLOURS, drawn_impacts, impulse_label, page, run_name
from ..signals import as_interrupts
from ..files import atomic_write
from .marks import RecordedRun, event_kind
from . import sketch as sk
from .sprites import HALF, sprite

#: Set to 1 to make :func:`serve` return once the replay is loaded (tests, scripts).
NO_WAIT_ENV = "PCMM_REPLAY_NO_WAIT"
ROOT = "pcmm"
#: How long an impact marker (and its arrow, at most) stays visible, s.
FLASH_S = 0.1
CAMERA_Z = 10.0
_WHITE = [1.0, 1.0, 1.0]
#: Default colours of links whose URDF visual has no ``<material>`` (one per link, in run order).
LINK_COLOURS = ((0.12, 0.47, 0.71), (1.0, 0.50, 0.05), (0.17, 0.63, 0.17), (0.84, 0.15, 0.16),
                (0.58, 0.40, 0.74), (0.55, 0.34, 0.29), (0.89, 0.47, 0.76), (0.74, 0.74, 0.13),
                (0.09, 0.75, 0.81), (0.50, 0.50, 0.50))
_GREY = (0.6, 0.6, 0.6, 1.0)  # the frame (root link) without a material
_ARROW_RGB = (0.80, 0.0, 0.0)
#: Plate styles (PIL colours) of the impulse labels and of the scale bar's label.
ARROW_LABEL = {"fill": (255, 255, 255), "ink": (160, 0, 0), "outline": (160, 0, 0)}
SCALE_LABEL = {"fill": (255, 255, 255), "outline": None}


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
    coloured: bool = True  # False: the URDF gives no material (rgba is a placeholder)

    @property
    def extent(self) -> float:
        """Half the largest dimension: how far the visual can reach past its origin."""
        if self.kind == "box":
            return 0.5 * float(np.linalg.norm(self.size[:2]))
        return float(max(self.size[0], 0.5 * self.size[-1]))

    def outline(self) -> np.ndarray:
        """(k, 2) points in the link frame whose hull contains the visual seen from +z."""
        if self.kind == "box":
            hx, hy, hz = (0.5 * s for s in self.size)
        elif self.kind == "cylinder":
            hx = hy = self.size[0]
            hz = 0.5 * self.size[1]
        else:
            hx = hy = hz = self.size[0]
        corners = np.array([[sx * hx, sy * hy, sz * hz, 1.0] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
        return (corners @ self.transform.T)[:, :2]


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


def read_visuals(urdf: str | Path, where: str | None = None) -> dict[str, list[Visual]]:
    """``{link: [Visual, ...]}`` for every link of ``urdf`` (links without visuals map to []).

    ``urdf`` is a file or the URDF's text (as a trajectory records it); ``where`` names it
    in messages."""
    is_text = isinstance(urdf, str) and urdf.lstrip().startswith("<")
    if not is_text:
        urdf = Path(urdf)
    where = where or ("URDF text" if is_text else str(urdf))
    try:
        root = ET.fromstring(urdf) if is_text else ET.parse(urdf).getroot()
    except (OSError, ET.ParseError) as exc:
        raise UsageError(f"{where}: cannot read the URDF for the replay: {exc}") from None
    urdf = where
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
                rgba, coloured = _GREY, False
                m = v.find("material")
                if m is not None:
                    c = m.find("color")
                    if c is not None and c.get("rgba") is not None:
                        rgba, coloured = _floats(c.get("rgba"), 4, rgba), True
                    elif m.get("name") in named:
                        rgba, coloured = named[m.get("name")], True
                shape = g[0] if g is not None and len(g) else None
                if shape is None:
                    continue
                if shape.tag == "box":
                    vis.append(Visual("box", _floats(shape.get("size"), 3, None), T, rgba, coloured))
                elif shape.tag == "cylinder":
                    vis.append(Visual("cylinder", (float(shape.get("radius")), float(shape.get("length"))),
                                      T, rgba, coloured))
                elif shape.tag == "sphere":
                    vis.append(Visual("sphere", (float(shape.get("radius")),), T, rgba, coloured))
                else:
                    print(terminal_text(f"pcmm: replay: {urdf}: link '{name}': <{shape.tag}> visuals are not "
                                        "shown (box, cylinder and sphere are)"), file=sys.stderr)
            except (TypeError, ValueError):
                raise UsageError(f"{urdf}: link '{name}': a <visual> has a malformed number") from None
        out[name] = vis
    return out


def visited(traj: RecordedRun) -> list[str]:
    return traj.visited()


def run_visuals(traj: RecordedRun) -> dict[str, dict[str, list[Visual]]]:
    """``{configuration: {link: [Visual]}}`` from the URDF text the trajectory recorded."""
    where = traj.source or "trajectory"
    return {c: read_visuals(v["urdf"], where=f"{where}: configuration '{c}' (recorded URDF)")
            for c, v in traj.configuration_views().items()}


def link_colours(traj: RecordedRun, visuals: dict[str, dict[str, list[Visual]]]) -> dict[str, tuple]:
    """Each link's default colour (for visuals without a material): the root link (the frame)
    grey, the others :data:`LINK_COLOURS` in the order the run lists its links."""
    roots = {link for per in visuals.values() for link in per
             if all(link != j["child"] for v in traj.views["configurations"].values() for j in v["joints"].values())}
    out, k = {}, 0
    for link in list(traj.links) + [lk for per in visuals.values() for lk in per]:
        if link in out:
            continue
        if link in roots:
            out[link] = _GREY
        else:
            out[link] = tuple(LINK_COLOURS[k % len(LINK_COLOURS)]) + (1.0,)
            k += 1
    return out


# ---- resampling --------------------------------------------------------------------------
def _span(runs) -> tuple[float, float]:
    for r in runs:
        if not r.segments:
            raise UsageError(f"{r.source or 'the trajectory'}: the trajectory is empty: nothing to replay")
    return min(float(r.segments[0].t[0]) for r in runs), max(float(r.segments[-1].t[-1]) for r in runs)


def frame_times(traj: RecordedRun | list, fps: float) -> np.ndarray:
    """The animation's frame times: ``t0 + k / fps`` (``round(duration * fps) + 1`` of them)
    plus every event's exact time (a grid time within 1e-9 s of an event becomes the event's)."""
    runs = traj if isinstance(traj, (list, tuple)) else [traj]
    if not runs or not all(r.segments for r in runs):
        raise UsageError("the trajectory is empty: nothing to replay")
    if not (fps > 0 and math.isfinite(fps)):
        raise UsageError(f"fps = {fps!r}: must be a finite number > 0")
    t0, t1 = _span(runs)
    n = max(1, int(round((t1 - t0) * fps)))
    grid = np.minimum(t0 + np.arange(n + 1) / fps, t1)
    events = np.array(sorted({float(e["t"]) for r in runs for e in r.events if t0 <= float(e["t"]) <= t1}))
    if events.size:
        i = np.clip(np.searchsorted(grid, events), 1, len(grid) - 1)
        near = np.where(np.abs(grid[i - 1] - events) <= np.abs(grid[i] - events), i - 1, i)
        hit = np.abs(grid[near] - events) <= 1e-9
        grid[near[hit]] = events[hit]
        grid = np.union1d(grid, events[~hit])
    return grid


def segment_at(traj: RecordedRun, times: np.ndarray) -> np.ndarray:
    """Index of the segment active at each time (at a switch instant: the new one)."""
    starts = np.array([s.t[0] for s in traj.segments])
    return np.clip(np.searchsorted(starts, times, side="right") - 1, 0, len(starts) - 1)


def resample(traj: RecordedRun, times: np.ndarray) -> tuple[dict[str, np.ndarray], np.ndarray]:
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


def event_frame(t: float, t0: float, fps: float, nframes: int | None = None) -> float:
    """The animation key (in frames, fractional) of time ``t``: every event has its own frame."""
    return (float(t) - t0) * fps


def _windows(times: np.ndarray, start: float, stop: float) -> tuple[int, int]:
    """Frame indices ``[a, b)`` whose times are in ``[start, stop)`` (``start`` is a frame time)."""
    a = int(np.searchsorted(times, start - 1e-12))
    b = int(np.searchsorted(times, stop - 1e-12))
    return a, max(b, a + 1)


def impact_flashes(traj: RecordedRun, times: np.ndarray) -> list[dict]:
    """Marker slots: ``[{"windows": [(first, last, (x, y)), ...]}]`` (frame indices into
    ``times``, inclusive); each flash starts at the impact's own frame."""
    slots: list[dict] = []
    for ev in traj.events:
        if not ev.get("impact", False) or ev.get("contact_point") is None:
            continue
        t = float(ev["t"])
        f, stop = _windows(times, t, t + FLASH_S)
        last = min(stop, len(times)) - 1
        p = tuple(float(c) for c in ev["contact_point"][:2])
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


def arrow_windows(traj: RecordedRun, times: np.ndarray) -> list[tuple[dict, int, int]]:
    """``[(event, first, last)]``: each impact's arrow, from its own frame until ``FLASH_S``
    later or the next impact at a later instant (frame indices, inclusive)."""
    evs = drawn_impacts(traj)
    out = []
    for i, ev in enumerate(evs):
        t = float(ev["t"])
        later = [float(e["t"]) for e in evs[i + 1:] if float(e["t"]) > t]
        a, b = _windows(times, t, min([t + FLASH_S] + later[:1]))
        out.append((ev, a, min(b, len(times)) - 1))
    return out


# ---- layout --------------------------------------------------------------------------------
@dataclass(frozen=True)
class View:
    """The fitted world window (the page widens its short side to the page's aspect, centred),
    where the plates and the scale bar go, and the impulse arrows' scale."""

    left: float
    right: float
    top: float
    bottom: float
    content: tuple  # ((xmin, ymin), (xmax, ymax)): everything the runs sweep
    label_xy: tuple[float, float]  # top left corner of the configuration plates
    label_h: float
    marker_r: float
    arrow_scale: float  # m per N·s
    arrow_width: float
    bar_length: float  # the scale bar, m
    bar_xy: tuple[float, float]  # its left end


def swept_points(traj: RecordedRun, visuals, times: np.ndarray) -> np.ndarray:
    """(n, 2) world points whose box contains every link's visuals (and frame origin) at every
    frame time."""
    poses, _ = resample(traj, times)
    pts = []
    for link, p in poses.items():
        local = [np.zeros((1, 2))] + [v.outline() for per in visuals.values() for v in per.get(link, [])]
        local = np.unique(np.concatenate(local), axis=0)
        c, s = np.cos(p[:, 2])[:, None], np.sin(p[:, 2])[:, None]
        x = p[:, :1] + c * local[:, 0] - s * local[:, 1]
        y = p[:, 1:2] + s * local[:, 0] + c * local[:, 1]
        pts.append(np.column_stack([x.ravel(), y.ravel()]))
    return np.concatenate(pts)


def _nice(x: float) -> float:
    """The largest 1, 2 or 5 times a power of ten not above ``x``."""
    k = math.floor(math.log10(x))
    return max(m * 10.0 ** k for m in (1, 2, 5) if m * 10.0 ** k <= x * (1 + 1e-12))


def side_offsets(runs, visuals: list, times: np.ndarray, layout: str) -> list[float]:
    """Each run's shift along x: none overlaid; side by side, each run right of the one before
    with a gap of 15 % of the widest run."""
    if layout == "overlay" or len(runs) == 1:
        return [0.0] * len(runs)
    if layout != "side":
        raise UsageError(f"--layout {layout!r}: must be 'overlay' or 'side'")
    boxes = [(p.min(axis=0), p.max(axis=0)) for p in (swept_points(r, v, times) for r, v in zip(runs, visuals))]
    gap = 0.15 * max(float(hi[0] - lo[0]) for lo, hi in boxes)
    out, right = [0.0], float(boxes[0][1][0])
    for lo, hi in boxes[1:]:
        dx = right + gap - float(lo[0])
        out.append(dx)
        right = float(hi[0]) + dx
    return out


def fitted_view(runs, visuals: list, times: np.ndarray, offsets=None) -> View:
    offsets = offsets or [0.0] * len(runs)
    pts = np.concatenate([swept_points(r, v, times) + [dx, 0.0] for r, v, dx in zip(runs, visuals, offsets)])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    span = max(float(np.max(hi - lo)), 1e-3)
    impacts = [(e, dx) for r, dx in zip(runs, offsets) for e in drawn_impacts(r)]
    p_max = max([abs(float(e["impulse"]["normal"])) for e, _ in impacts] + [0.0])
    arrow_scale = 0.3 * span / p_max if p_max > 0 else 0.0
    for e, dx in impacts:  # the arrows are in view too
        tip = np.asarray(e["contact_point"][:2]) + arrow_scale * np.asarray(e["impulse"]["vector"][:2]) + [dx, 0.0]
        lo, hi = np.minimum(lo, tip), np.maximum(hi, tip)
    span = max(float(np.max(hi - lo)), 1e-3)
    margin = max(0.06 * span, HALF * 1.1 * max(sk.scale(r) for r in runs))  # the symbols' sprites too
    label_h = 0.06 * span
    left, right = float(lo[0] - margin), float(hi[0] + margin)
    top = float(hi[1] + margin + 1.5 * label_h)
    bottom = float(lo[1] - margin - 2.2 * label_h)
    bar = _nice(0.25 * (right - left))
    return View(left=left, right=right, top=top, bottom=bottom,
                content=((float(lo[0]), float(lo[1])), (float(hi[0]), float(hi[1]))),
                label_xy=(left + 0.3 * label_h, top - 0.3 * label_h), label_h=float(label_h),
                marker_r=float(max(0.015 * span, 1e-4)), arrow_scale=float(arrow_scale),
                arrow_width=float(0.012 * span), bar_length=float(bar),
                bar_xy=(left + 0.5 * label_h, bottom + 1.45 * label_h))


def view_box(traj: RecordedRun, visuals: dict[str, dict[str, list[Visual]]], fps: float = 60) -> View:
    """The fitted view of one run (see :func:`fitted_view`)."""
    return fitted_view([traj], [visuals], frame_times(traj, fps))


@functools.lru_cache(maxsize=1024)  # an event plate's text is drawn at each of its fading steps
def _label_png(text: str, fill=(255, 244, 204), ink=(20, 20, 20), outline=(120, 100, 40),
               border: int = 3) -> tuple[bytes, float]:
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
    img = Image.new("RGB", (w, h), fill)
    draw = ImageDraw.Draw(img)
    if outline is not None:
        draw.rectangle([0, 0, w - 1, h - 1], outline=outline, width=border)
    draw.text((pad - x0, pad - y0), text, fill=ink, font=font)
    buf = io.BytesIO()
    img.save(buf, format="PNG")
    return buf.getvalue(), w / h


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


class _Recorder:
    """A meshcat window that keeps every command (msgpack, in order) for the offline page and
    forwards it to a live meshcat window if there is one.

    Each distinct picture (a texture's data URL: a symbol's sprite, a label) is kept once in
    ``images``; the kept commands name it ``pcmm-image:<index>`` (:data:`pcmm.viz.page.IMAGE_REF`),
    which the page resolves before meshcat reads the command.  The cycle's page to 2.3 s has 653
    textures of 419 distinct pictures (its 210 symbol sprites: 6), 7.3 MB instead of 10.0."""

    def __init__(self, live=None):
        self.commands: list[bytes] = []
        self.images: list[str] = []
        self._image_index: dict[str, int] = {}
        self.live = live

    def send(self, command):
        import umsgpack  # meshcat's own dependency
        lowered = command.lower()
        if lowered.get("type") == "set_object":
            for image in lowered["object"].get("images", ()):
                url = image.get("url")
                if isinstance(url, str) and url.startswith("data:"):
                    k = self._image_index.setdefault(url, len(self.images))
                    if k == len(self.images):
                        self.images.append(url)
                    image["url"] = f"{IMAGE_REF}{k}"
        self.commands.append(umsgpack.packb(lowered))
        if self.live is not None:
            self.live.send(command)


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


def _translation(x, y, z=0.0, angle=0.0) -> np.ndarray:
    T = np.eye(4)
    c, s = math.cos(angle), math.sin(angle)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:3, 3] = [x, y, z]
    return T


def _plate(node, text: str, height: float, anchor_xy, z: float, align: str = "left", opacity: float = 1.0,
           **colours) -> float:
    """A text plate of ``height`` (world units) with its left edge, centre or right edge
    (``align``) at ``anchor_xy[0]`` and its top at ``anchor_xy[1]``; returns its width."""
    g = _import_meshcat().geometry
    png, aspect = _label_png(text, **colours)
    width = height * aspect
    node.set_object(g.Box([width, height, 1e-4]),
                    g.MeshBasicMaterial(map=g.ImageTexture(image=g.PngImage(png)), color=0xFFFFFF,
                                        opacity=float(opacity), transparent=bool(opacity < 1)))
    x = anchor_xy[0] + {"left": 0.5, "centre": 0.0, "right": -0.5}[align] * width
    node.set_transform(_translation(x, anchor_xy[1] - 0.5 * height, z))
    return width


def arrow_parts(length: float, width: float) -> tuple[float, float]:
    """(shaft, head) lengths of an arrow of total ``length``."""
    head = min(0.35 * length, 3.0 * width)
    return length - head, head


def _send_arrow(node, ev: dict, view: View, rgb) -> None:
    """The impulse of ``ev`` on body b: from the contact point along ``P n``, ``arrow_scale * |P|`` long."""
    g = _import_meshcat().geometry
    vec = np.asarray(ev["impulse"]["vector"][:2], float)
    length = view.arrow_scale * float(np.linalg.norm(vec))
    shaft, head = arrow_parts(length, view.arrow_width)
    x, y = (float(c) for c in ev["contact_point"][:2])
    angle = math.atan2(vec[1], vec[0])
    material = g.MeshBasicMaterial(color=_rgba_int(rgb))
    node.set_transform(_translation(x, y, 0.6))
    body = node["arrow"]  # +y of the arrow along the impulse
    body.set_transform(_translation(0.0, 0.0, 0.0, angle - 0.5 * math.pi))
    body["shaft"].set_object(g.Box([view.arrow_width, shaft, 1e-3]), material)
    body["shaft"].set_transform(_translation(0.0, 0.5 * shaft))
    body["head"].set_object(g.Cylinder(head, radiusTop=0.0, radiusBottom=1.6 * view.arrow_width), material)
    body["head"].set_transform(_translation(0.0, shaft + 0.5 * head))
    tip = length * np.array([math.cos(angle), math.sin(angle)])
    h = 0.8 * view.label_h
    # the plate beside the tip, on the side the arrow points to
    ax = tip[0] + (0.3 * h if tip[0] >= 0 else -0.3 * h)
    _plate(node["label"], impulse_label(ev), h, (ax, tip[1] + 0.5 * h), 0.05,
           align="left" if tip[0] >= 0 else "right", **ARROW_LABEL)


class _TopCamera:
    """An orthographic camera on +z looking down (x right, y up)."""

    def __new__(cls, view: View):
        g = _import_meshcat().geometry

        class TopCamera(g.OrthographicCamera):
            def lower(self):
                data = super().lower()
                m = np.eye(4)
                m[2, 3] = CAMERA_Z
                data["object"]["matrix"] = [float(x) for x in m.T.flatten()]  # three.js: column-major
                return data
        return TopCamera(view.left, view.right, view.top, view.bottom, 0.01, 10 * CAMERA_Z)



#: The symbols' heights above the links (z, m): later ones drawn over earlier ones.
_SYMBOL_Z = {"ground": 0.40, "guide": 0.40, "stop": 0.41, "pivot": 0.42, "slider": 0.43, "revolute": 0.44,
             "cut": 0.45, "locked": 0.46}
#: An event plate's height, in configuration plates' heights.
PLATE_H = 0.75
#: A plate fades out in this many steps of opacity over its time (sketch.PLATE_S).
_FADE = (1.0, 0.6, 0.3)
PLATE_COLOURS = {"impact": (160, 0, 0), "merge": (100, 40, 150), "release": (20, 120, 40), "switch": (60, 60, 60)}


def _sprite_material(png: bytes, opacity: float = 1.0):
    g = _import_meshcat().geometry
    return g.MeshBasicMaterial(map=g.ImageTexture(image=g.PngImage(png)), color=0xFFFFFF, transparent=True,
                               opacity=float(opacity))


def _send_sketch(base, traj: RecordedRun, poses, frame_config, times, keys, view, clip, bool_track,
                 ghost: bool = False) -> None:
    """The engineer's symbols of :mod:`pcmm.viz.sketch` on the links' nodes (shown exactly in the
    configurations they belong to), and the events' plates (riding on their bodies, fading out)
    and joint-stop moment arcs (``links/<link>/sym/<i>``, ``plates/<i>``, ``links/<link>/arcs/<i>``)."""
    g = _import_meshcat().geometry
    s = sk.scale(traj)
    box = g.Box([2 * HALF * s, 2 * HALF * s, 1e-4])
    for i, sym in enumerate(sk.symbols(traj)):
        if sym.link not in poses:
            continue
        node = base[f"links/{sym.link}/sym/{i}"]
        if sym.kind == "guide":  # two lines along the axis
            for side, off in (("l", -0.6 * s), ("r", 0.6 * s)):
                node[side].set_object(g.Box([13 * s, 0.12 * s, 1e-4]), g.MeshBasicMaterial(color=0x000000))
                node[side].set_transform(_translation(5.4 * s, off, 0.0))
        else:
            node.set_object(box, _sprite_material(sprite(sym.kind, sym.shape), 0.5 if ghost else 1.0))
        node.set_transform(_translation(sym.xy[0], sym.xy[1], _SYMBOL_Z[sym.kind], sym.angle))
        if sym.configurations is not None or sym.window is not None:
            # shown in its configurations and, for a point pinned where it struck, for that stay only
            bool_track(clip(node), [sym.shown(c, float(t)) for c, t in zip(frame_config, times)])
    if ghost:
        return
    h = PLATE_H * view.label_h
    for i, mark in enumerate(m for m in sk.event_marks(traj) if m.kind == "plate"):
        a, b = _windows(times, *mark.window)
        b = min(b, len(times))
        node = base[f"plates/{i}"]
        placed = [sk.world(traj, [mark], float(t)) for t in times[a:b]]
        pts = [p[0].xy if p else (0.0, 0.0) for p in placed]
        c = clip(node)
        from_meshcat = _import_meshcat().animation
        c.tracks["position"] = from_meshcat.AnimationTrack(
            "position", "vector3", [keys[k] for k in range(a, b)], [[float(x), float(y), 0.55] for x, y in pts])
        ink = PLATE_COLOURS.get(mark.extra.get("kind"), PLATE_COLOURS["switch"])
        t0, t1 = mark.window
        for j, opacity in enumerate(_FADE):
            lo, hi = t0 + j * (t1 - t0) / len(_FADE), t0 + (j + 1) * (t1 - t0) / len(_FADE)
            step = node[f"fade{j}"]
            _plate(step, mark.text, h, (0.8 * s, 0.8 * s + h), 0.0, opacity=opacity, fill=(255, 255, 255),
                   ink=ink, outline=ink, border=7)
            on = np.zeros(len(times), dtype=bool)
            fa, fb = _windows(times, lo, hi)
            on[fa:min(fb, len(times))] = True
            if j == 0:
                on[a] = True  # the event's own frame shows the plate
            bool_track(clip(step), on)
    for i, mark in enumerate(m for m in sk.event_marks(traj) if m.kind == "arc"):
        a, b = _windows(times, *mark.window)
        on = np.zeros(len(times), dtype=bool)
        on[a:min(b, len(times))] = True
        node = base[f"links/{mark.link}/arcs/{i}"]
        node.set_object(box, _sprite_material(sprite("arc", mark.shape)))
        node.set_transform(_translation(mark.xy[0], mark.xy[1], 0.58))
        bool_track(clip(node), on)
        label = base[f"arcs/{i}"]
        x, y = sk.world(traj, [mark], float(mark.window[0]))[0].xy
        _plate(label, mark.text, h, (x + 1.4 * s, y - 1.0 * s), 0.59, **ARROW_LABEL)
        bool_track(clip(label), on)

def frame_boxes(runs, visuals: list, times: np.ndarray, offsets, mode: str, hold_s: float = 0.25) -> list | None:
    """The view per frame: ``None`` for the whole run's box (``run``); else ``[left, right,
    bottom, top]`` per frame, around what the runs cover at that frame (``follow``: the union
    over ``hold_s`` either side, so the view does not shake), or over the stay in the first run's
    configuration at that frame (``configuration``), with a 10 % margin."""
    if mode == "run":
        return None
    if mode not in ("follow", "configuration"):
        raise UsageError(f"--view {mode!r}: must be 'follow', 'configuration' or 'run'")
    lo = np.full((len(times), 2), np.inf)
    hi = np.full((len(times), 2), -np.inf)
    for r, v, dx in zip(runs, visuals, offsets):
        poses, _ = resample(r, times)
        for link, p in poses.items():
            local = np.concatenate([np.zeros((1, 2))] + [vi.outline() for per in v.values() for vi in per.get(link, [])])
            c, s = np.cos(p[:, 2])[:, None], np.sin(p[:, 2])[:, None]
            x = p[:, :1] + c * local[:, 0] - s * local[:, 1] + dx  # (frames, points)
            y = p[:, 1:2] + s * local[:, 0] + c * local[:, 1]
            lo = np.minimum(lo, np.column_stack([x.min(axis=1), y.min(axis=1)]))
            hi = np.maximum(hi, np.column_stack([x.max(axis=1), y.max(axis=1)]))
    if mode == "follow":
        dt = float(np.median(np.diff(times))) if len(times) > 1 else 1.0
        w = max(1, int(round(hold_s / max(dt, 1e-12))))
        lo = np.array([lo[max(0, k - w):k + w + 1].min(axis=0) for k in range(len(times))])
        hi = np.array([hi[max(0, k - w):k + w + 1].max(axis=0) for k in range(len(times))])
    else:
        seg = segment_at(runs[0], times)
        for i in np.unique(seg):
            rows = seg == i
            lo[rows], hi[rows] = lo[rows].min(axis=0), hi[rows].max(axis=0)
    span = np.maximum((hi - lo).max(axis=1, keepdims=True), 1e-3)
    lo, hi = lo - 0.1 * span, hi + 0.1 * span
    return [[round(float(a), 6) for a in (l[0], h[0], l[1], h[1])] for l, h in zip(lo, hi)]


def envelope(traj: RecordedRun, visuals, times: np.ndarray) -> dict[str, np.ndarray]:
    """``{link: (n, 2)}``: the path of each moving link's farthest visual point (its tip) over
    the frames, the swept envelope the page traces faintly."""
    poses, _ = resample(traj, times)
    out = {}
    for link, p in poses.items():
        if np.ptp(p[:, :2], axis=0).max() < 1e-12 and np.ptp(p[:, 2]) < 1e-12:
            continue  # the frame does not move
        local = [v.outline() for per in visuals.values() for v in per.get(link, [])]
        if not local:
            continue
        local = np.concatenate(local)
        tip = local[np.argmax(np.hypot(local[:, 0], local[:, 1]))]
        c, s = np.cos(p[:, 2]), np.sin(p[:, 2])
        out[link] = np.column_stack([p[:, 0] + c * tip[0] - s * tip[1], p[:, 1] + s * tip[0] + c * tip[1]])
    return out


def _send_scene(vis, runs: list[RecordedRun], fps: float, layout: str = "overlay", view_mode: str = "run") -> dict:
    """Send every visited configuration's geometry, the plates, markers, arrows, scale bar and
    camera, and the whole of each run as one animation; return what the page needs."""
    mc = _import_meshcat()
    g = mc.geometry
    Animation, AnimationClip, AnimationTrack = (mc.animation.Animation, mc.animation.AnimationClip,
                                                mc.animation.AnimationTrack)
    visuals = [run_visuals(r) for r in runs]
    t0, t1 = _span(runs)
    times = frame_times(list(runs), fps)
    keys = [float(k) for k in (times - t0) * fps]  # animation keys, in frames
    offsets = side_offsets(runs, visuals, times, layout)
    view = fitted_view(runs, visuals, times, offsets)
    boxes = frame_boxes(runs, visuals, times, offsets, view_mode)

    vis["/Cameras/default"].set_transform(np.eye(4))
    vis["/Cameras/default/rotated"].set_transform(np.eye(4))
    vis["/Cameras/default/rotated"].set_object(_TopCamera(view))
    vis["/Background"].set_property("top_color", _WHITE)
    vis["/Background"].set_property("bottom_color", _WHITE)
    vis["/Grid"].set_property("visible", False)
    vis["/Axes"].set_property("visible", False)

    anim = Animation(default_framerate=fps)

    def clip(node):
        c = AnimationClip(fps=fps)
        anim.clips[node.path] = c
        return c

    def bool_track(c, per_frame):
        """Per-frame booleans as a discrete track: keys at the first frame and at every change."""
        frames, values = [], []
        for k, val in enumerate(per_frame):
            if k == 0 or bool(val) != values[-1]:
                frames.append(keys[k])
                values.append(bool(val))
        c.tracks["visible"] = AnimationTrack("visible", "boolean", frames, values)

    # the scale bar: a round length, bottom left
    bx, by = view.bar_xy
    thick = 0.12 * view.label_h
    vis[ROOT]["scale/bar"].set_object(g.Box([view.bar_length, thick, 1e-4]), g.MeshBasicMaterial(color=0x111111))
    vis[ROOT]["scale/bar"].set_transform(_translation(bx + 0.5 * view.bar_length, by, 0.5))
    for side, x in (("l", bx), ("r", bx + view.bar_length)):
        vis[ROOT][f"scale/tick_{side}"].set_object(g.Box([thick, 0.6 * view.label_h, 1e-4]),
                                                   g.MeshBasicMaterial(color=0x111111))
        vis[ROOT][f"scale/tick_{side}"].set_transform(_translation(x, by, 0.5))
    _plate(vis[ROOT]["scale/label"], f"{view.bar_length:g} m", 0.8 * view.label_h,
           (bx + 0.5 * view.bar_length, by - 0.25 * view.label_h), 0.5, align="centre", **SCALE_LABEL)

    info = {"frames": len(times), "fps": fps, "view": view, "impact_markers": 0, "arrows": 0,
            "times": times, "t0": t0, "t1": t1, "boxes": boxes, "offsets": offsets, "layout": layout}
    several = len(runs) > 1
    for r, (traj, per_config) in enumerate(zip(runs, visuals)):
        base = vis[ROOT] if r == 0 else vis[ROOT][f"run{r + 1}"]
        if r:
            base.set_transform(_translation(offsets[r] - offsets[0], 0.0))
        if view_mode != "run":  # the swept envelope, a faint trace under everything
            line = mc.geometry.LineBasicMaterial(color=0xC8C8C8)
            for link, path in envelope(traj, per_config, times).items():
                pts = np.vstack([path.T, np.full(len(path), -0.05)])
                base[f"envelope/{link}"].set_object(mc.geometry.Line(mc.geometry.PointsGeometry(pts), line))
        poses, seg_idx = resample(traj, times)
        frame_config = [traj.segments[i].configuration for i in seg_idx]
        if r == 0:  # the readout's link angles: the links that turn
            info["angles"] = {link: p[:, 2] for link, p in poses.items() if np.ptp(p[:, 2]) > 1e-9}
        own = link_colours(traj, per_config)
        for config, per_link in per_config.items():
            for link, vs in per_link.items():
                if link not in poses:
                    print(terminal_text(f"pcmm: replay: link '{link}' of configuration '{config}' is not in "
                                        "the trajectory; its visuals stay at the origin"), file=sys.stderr)
                for i, v in enumerate(vs):
                    if several:
                        if own[link] == _GREY and r and layout == "overlay":  # one frame is enough
                            continue
                        ghost = r > 0 and layout == "overlay"  # the second run overlaid: a ghost
                        rgba = own[link] if own[link] == _GREY else tuple(RUN_COLOURS[r % len(RUN_COLOURS)]) + (
                            0.4 if ghost else 1.0,)
                    else:
                        rgba = v.rgba if v.coloured else own[link]
                    geom, T = _geometry(v)
                    node = base[f"links/{link}/{config}/visual{i}"]
                    node.set_object(geom, g.MeshPhongMaterial(color=_rgba_int(rgba), opacity=float(rgba[3]),
                                                              transparent=bool(rgba[3] < 1)))
                    node.set_transform(T @ _translation(0, 0, -0.01 * r))
        if r == 0:
            for config in per_config:
                _plate(base[f"labels/{config}"], config, view.label_h, view.label_xy, 0.5)
        for link, p in poses.items():
            c = clip(base[f"links/{link}"])
            half = 0.5 * p[:, 2]
            c.tracks["position"] = AnimationTrack(
                "position", "vector3", list(keys), [[float(x), float(y), 0.0] for x, y in p[:, :2]])
            c.tracks["quaternion"] = AnimationTrack(  # three.js order: x, y, z, w
                "quaternion", "quaternion", list(keys),
                [[0.0, 0.0, float(s), float(w)] for s, w in zip(np.sin(half), np.cos(half))])
        for config, per_link in per_config.items():
            shown = [fc == config for fc in frame_config]
            for link, vs in per_link.items():
                if vs:
                    bool_track(clip(base[f"links/{link}/{config}"]), shown)
            if r == 0:
                bool_track(clip(base[f"labels/{config}"]), shown)
        # impact markers (red spheres)
        slots = impact_flashes(traj, times)
        for i, slot in enumerate(slots):
            node = base[f"impacts/{i}"]
            node["marker"].set_object(g.Sphere(view.marker_r), g.MeshBasicMaterial(color=0xE00000, opacity=0.85,
                                                                                  transparent=True))
            c = clip(node)
            on = np.zeros(len(times), dtype=bool)
            frames, values = [], []
            for a, b, (x, y) in slot["windows"]:
                on[a:b + 1] = True
                frames += [keys[a], keys[b]]
                values += [[x, y, 0.3], [x, y, 0.3]]
            c.tracks["position"] = AnimationTrack("position", "vector3", frames, values)
            bool_track(c, on)
        # impulse arrows
        arrows = arrow_windows(traj, times) if view.arrow_scale > 0 else []
        rgb = _ARROW_RGB if not several else RUN_COLOURS[r % len(RUN_COLOURS)]
        for i, (ev, a, b) in enumerate(arrows):
            node = base[f"arrows/{i}"]
            _send_arrow(node, ev, view, rgb)
            on = np.zeros(len(times), dtype=bool)
            on[a:b + 1] = True
            bool_track(clip(node), on)
        _send_sketch(base, traj, poses, frame_config, times, keys, view, clip, bool_track,
                     ghost=r > 0 and layout == "overlay")
        info["impact_markers"] += len(slots)
        info["arrows"] += len(arrows)
    vis.set_animation(anim, play=True, repetitions=1)
    return info


def _build(runs, fps: float, live=None, layout: str = "overlay", view: str = "run") -> tuple[str, dict]:
    mc = _import_meshcat()
    rec = _Recorder(live)
    info = _send_scene(mc.Visualizer(window=rec), runs, fps, layout, view)
    return page(runs, info, rec.commands, rec.images), info


def html_page(traj: RecordedRun, fps: float = 60, others=(), layout: str = "overlay", view: str = "run") -> str:
    """The self-contained replay page (text); ``others`` overlaid (the second a ghost) or side by
    side (``layout``), the view fitted to the whole ``run``, each ``configuration`` or ``follow``-ing."""
    return _build([traj, *others], fps, layout=layout, view=view)[0]


def write_html(traj: RecordedRun, path: str | Path, fps: float = 60, others=(), layout: str = "overlay",
               view: str = "run") -> Path:
    """Write ONE offline HTML page replaying ``traj`` (atomically; overwrites ``path``).

    The page embeds meshcat's viewer and the commands; it needs no server and
    no network."""
    html = html_page(traj, fps, others, layout, view)
    return atomic_write(path, lambda f: f.write(html), force=True)


class Inline:
    """The replay page for a Jupyter cell: an ``<iframe srcdoc>`` (no server, no network)."""

    def __init__(self, traj: RecordedRun, *others: RecordedRun, fps: float = 60, height: int = 520,
                 layout: str = "overlay", view: str = "run"):
        self.html = html_page(traj, fps, others, layout, view)
        self.height = int(height)

    def _repr_html_(self) -> str:
        doc = self.html.replace("&", "&amp;").replace('"', "&quot;")
        return (f'<iframe class="pcmm-replay" srcdoc="{doc}" style="width: 100%; height: {self.height}px; '
                'border: 1px solid #ccc" title="pcmm replay"></iframe>')

    def save(self, path: str | Path) -> Path:
        return atomic_write(path, lambda f: f.write(self.html), force=True)


@contextlib.contextmanager
def _page_server(page: str):
    """Serve ``page`` at ``http://127.0.0.1:<port>/`` from a thread; always shut down on exit."""
    from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
    body = page.encode("utf-8")

    class Handler(BaseHTTPRequestHandler):
        def do_GET(self):  # noqa: N802 - http.server's name
            if self.path.split("?")[0] not in ("/", "/index.html"):
                self.send_error(404)
                return
            self.send_response(200)
            self.send_header("Content-Type", "text/html; charset=utf-8")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args):
            pass

    server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}/"
    finally:
        server.shutdown()
        server.server_close()
        thread.join(timeout=5)


def serve(traj: RecordedRun, fps: float = 60, others=(), layout: str = "overlay", view: str = "run") -> None:
    """Replay ``traj`` live: the scene goes to a meshcat server (its own viewer URL), and the
    replay page (readout, timeline, the same scene) is served on 127.0.0.1.  Print both URLs,
    block until Ctrl-C (or return at once when ``PCMM_REPLAY_NO_WAIT=1``).  Both servers are
    always shut down."""
    runs = [traj, *others]
    with as_interrupts(), _meshcat() as vis:  # SIGTERM / SIGHUP shut the servers down like Ctrl-C
        page, info = _build(runs, fps, live=vis.window, layout=layout, view=view)
        with _page_server(page) as url:
            print(f"pcmm replay: {terminal_text(' vs '.join(run_name(r) for r in runs))}: {info['frames']} frames at "
                  f"{fps:g} fps; open {url} in a browser (time readout, event timeline; "
                  f"meshcat's own viewer: {vis.url()})", flush=True)
            if os.environ.get(NO_WAIT_ENV, "") not in ("", "0"):
                return
            print("pcmm replay: press Ctrl-C to stop the server", flush=True)
            try:
                while vis.window.server_proc.poll() is None:
                    time.sleep(0.5)
                print("pcmm replay: the meshcat server stopped", file=sys.stderr)
            except KeyboardInterrupt:
                print("pcmm replay: stopped", flush=True)


__all__ = ["serve", "write_html", "html_page", "Inline", "read_visuals", "run_visuals", "frame_times", "resample",
           "fitted_view", "view_box", "impact_flashes", "arrow_windows", "event_frame", "event_kind", "BAR_PX",
           "NO_WAIT_ENV"]
