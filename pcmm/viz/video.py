"""A video of a recorded run for the paper and the talk: the 2D sketch (:mod:`pcmm.viz.draw2d`)
with the time readout, the event plates and the impulse arrows, frame by frame, written by
matplotlib's animation writers (MP4 through ffmpeg, GIF through Pillow).

The video runs at ``speed`` simulated seconds per second of video, slowed by ``slow`` within
``window`` s of every event (slow motion around the impacts).  Its clock is exact: the video
time of simulated time ``t`` is ``tau(t) = integral of 1 / rate``, piecewise linear, and frame
``k`` shows the simulated time whose ``tau`` is ``k / fps`` (:func:`frame_times`), so a video of
``tau(t1) * fps`` seconds' frames has ``floor(tau(t1) * fps) + 1`` frames.  The frame nearest to
each event shows the event's exact instant (its impulse arrow, its plate).
"""
from __future__ import annotations

import math
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import UsageError
from .marks import RecordedRun
from .draw2d import Sketch, draw_frame, _union


@dataclass(frozen=True)
class Clock:
    """The video's clock: ``speed`` simulated s per video s, times ``slow`` near events."""

    t0: float
    t1: float
    speed: float = 1.0
    slow: float = 0.1
    window: float = 0.02
    events: tuple = ()

    def slow_spans(self) -> list[tuple[float, float]]:
        """The union of ``[te - window, te + window]`` over the events, clipped to the run."""
        spans = []
        for te in sorted(self.events):
            a, b = max(self.t0, te - self.window), min(self.t1, te + self.window)
            if b <= a:
                continue
            if spans and a <= spans[-1][1]:
                spans[-1] = (spans[-1][0], max(spans[-1][1], b))
            else:
                spans.append((a, b))
        return spans

    def knots(self) -> tuple[np.ndarray, np.ndarray]:
        """``(t, tau)`` at the ends of the slow spans: ``tau`` is linear between them."""
        ts, taus = [self.t0], [0.0]
        for a, b in self.slow_spans():
            taus.append(taus[-1] + (a - ts[-1]) / self.speed)
            ts.append(a)
            taus.append(taus[-1] + (b - a) / (self.speed * self.slow))
            ts.append(b)
        taus.append(taus[-1] + (self.t1 - ts[-1]) / self.speed)
        ts.append(self.t1)
        return np.array(ts), np.array(taus)

    @property
    def duration(self) -> float:
        return float(self.knots()[1][-1])


def frame_times(clock: Clock, fps: float) -> np.ndarray:
    """The simulated time of every frame: ``tau^-1(k / fps)`` for ``k = 0 .. floor(duration fps)``,
    each event's frame (the nearest one not yet taken) moved onto the event's exact instant."""
    ts, taus = clock.knots()
    n = int(math.floor(clock.duration * fps + 1e-9)) + 1
    times = np.interp(np.arange(n) / fps, taus, ts)
    taken = set()
    for te in sorted(clock.events):
        if not (clock.t0 <= te <= clock.t1):
            continue
        k = int(np.argmin(np.abs(times - te)))
        if k not in taken:
            times[k] = te
            taken.add(k)
    return times


def write_video(run: RecordedRun, path: str | Path, others=(), fps: float = 30.0, speed: float = 1.0,
                slow: float = 0.1, window: float = 0.02, size=(8.0, 5.0), dpi: int = 100) -> dict:
    """Write the video of ``run`` (``others`` as dashed ghosts) to ``path`` (.mp4 or .gif).
    Returns ``{"frames", "times", "box", "figsize", "dpi", "axes"}`` (what a test needs to find a
    world point's pixel)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".mp4", ".gif"):
        raise UsageError(f"--video {path}: a video is written as .mp4 or .gif, not '{path.suffix}'")
    for name, val in (("fps", fps), ("speed", speed), ("slow", slow)):
        if not (val > 0 and math.isfinite(val)):
            raise UsageError(f"--{name} {val!r}: must be a finite number > 0")
    if window < 0:
        raise UsageError(f"--slow-window {window!r}: must be >= 0 s")
    if suffix == ".mp4" and shutil.which("ffmpeg") is None:
        raise UsageError(f"--video {path}: an MP4 needs ffmpeg, which is not installed (Debian: apt-get install "
                         "ffmpeg), or write a .gif")
    if not run.segments:
        raise UsageError(f"{run.source or 'the trajectory'}: the trajectory is empty: no video")
    from matplotlib import animation
    from .canvas import _matplotlib
    Figure = _matplotlib()
    runs = [run, *others]
    t0 = min(float(r.segments[0].t[0]) for r in runs)
    t1 = max(float(r.segments[-1].t[-1]) for r in runs)
    clock = Clock(t0, t1, speed, slow, window, tuple(float(e["t"]) for e in run.events))
    times = frame_times(clock, fps)
    sketches = [Sketch(run)] + [Sketch(o, colour="#888888", ghost=True) for o in others]
    box = _union([s.extent(np.linspace(t0, t1, 60)) for s in sketches])
    fig = Figure(figsize=size, dpi=dpi)
    names = [r.scene_name + ("" if r.impact else " (without impact)") for r in runs]
    layout = {}

    if suffix == ".mp4":
        writer = animation.FFMpegWriter(fps=fps, codec="libx264", extra_args=["-pix_fmt", "yuv420p"])
    else:
        writer = animation.PillowWriter(fps=fps)
    if not path.parent.is_dir():
        raise UsageError(f"--video {path}: folder {path.parent} does not exist")
    tmp = path.with_name(f".{path.stem}.partial{suffix}")  # the writers need the real suffix; renamed when done
    try:
        with writer.saving(fig, str(tmp), dpi):
            for t in times:
                fig.clear()
                out = draw_frame(fig, sketches, float(t), box, names=names)
                writer.grab_frame()
                layout["axes"] = out["ax"].get_position().bounds  # drawn: the box the equal aspect left
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return {"frames": len(times), "times": times, "box": box, "figsize": size, "dpi": dpi,
            "axes": layout.get("axes"), "clock": clock}


def pixel_of(info: dict, x: float, y: float) -> tuple[int, int]:
    """The (column, row) pixel of world point (x, y) in a frame of the video ``info`` describes
    (the axes keep the box's aspect: matplotlib shrinks the box's long side to fit)."""
    W, H = info["figsize"][0] * info["dpi"], info["figsize"][1] * info["dpi"]
    ax0, ay0, aw, ah = info["axes"]
    xmin, xmax, ymin, ymax = info["box"]
    pw, ph = aw * W, ah * H
    sx = min(pw / (xmax - xmin), ph / (ymax - ymin))  # equal aspect: one scale, centred
    cx, cy = ax0 * W + 0.5 * pw, ay0 * H + 0.5 * ph
    px = cx + (x - 0.5 * (xmin + xmax)) * sx
    py = cy + (y - 0.5 * (ymin + ymax)) * sx
    return int(round(px)), int(round(H - py))
