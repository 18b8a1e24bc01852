"""`pcmm replay --video`: the frame count its clock promises, decoded from the file, and the
frame at the first impact showing the impulse arrow (red pixels along it, none a frame before)."""
from __future__ import annotations

import math
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

import pcmm
from pcmm.cli import main
from pcmm.results.trajectory import Trajectory
from pcmm.viz import video

ROOT = Path(__file__).resolve().parents[1]
FPS, SPEED, SLOW, WINDOW = 10.0, 1.0, 0.25, 0.01
needs_ffmpeg = pytest.mark.skipif(shutil.which("ffmpeg") is None, reason="needs ffmpeg (Debian: apt-get install ffmpeg)")


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """Example 4 over its first 0.12 s (its first impacts, joint stops at O3 and O2)."""
    traj = pcmm.simulate(pcmm.load_scene(ROOT / "examples" / "three_bar_cycle.toml"), pcmm.RunOptions(t_end=0.12))
    path = tmp_path_factory.mktemp("video") / "run.npz"
    traj.save(path)
    return path, Trajectory.load(path)


def _video_time(events, t, t0=0.0, t1=0.12):
    """The video time of simulated time ``t``, by hand: 1/SPEED s per s, 1/(SPEED SLOW) within
    WINDOW of an event (the union of the windows)."""
    spans = []
    for te in sorted(events):
        a, b = max(t0, te - WINDOW), min(t1, te + WINDOW)
        if spans and a <= spans[-1][1]:
            spans[-1][1] = max(spans[-1][1], b)
        else:
            spans.append([a, b])
    slow = sum(max(0.0, min(b, t) - a) for a, b in spans)
    return (t - t0 - slow) / SPEED + slow / (SPEED * SLOW)


def _decode(path: Path, k: int) -> np.ndarray:
    from PIL import Image
    if path.suffix == ".gif":
        im = Image.open(path)
        im.seek(k)
        return np.asarray(im.convert("RGB")).astype(int)
    png = path.with_name(f"{path.stem}_{k}.png")
    subprocess.run(["ffmpeg", "-v", "error", "-y", "-i", str(path), "-vf", f"select=eq(n\\,{k})", "-vframes", "1",
                    str(png)], check=True)
    return np.asarray(Image.open(png).convert("RGB")).astype(int)


def _count(path: Path) -> int:
    if path.suffix == ".gif":
        from PIL import Image
        return Image.open(path).n_frames
    out = subprocess.run(["ffprobe", "-v", "error", "-count_frames", "-select_streams", "v:0", "-show_entries",
                          "stream=nb_read_frames", "-of", "csv=p=0", str(path)], check=True, capture_output=True,
                         text=True).stdout
    return int(out.strip())


@pytest.mark.parametrize("suffix", [pytest.param(".mp4", marks=needs_ffmpeg), ".gif"])
def test_the_video_has_its_frames_and_shows_the_impulse_at_the_first_impact(run, suffix, tmp_path, capsys):
    path, traj = run
    out = tmp_path / f"run{suffix}"
    args = ["replay", str(path), "--video", str(out), "--fps", str(FPS), "--speed", str(SPEED), "--slow", str(SLOW),
            "--slow-window", str(WINDOW)]
    assert main(args) == 0
    events = [e["t"] for e in traj.events]
    duration = _video_time(events, 0.12)
    expected = math.floor(duration * FPS + 1e-9) + 1
    assert f"video: {out} ({expected} frames at {FPS:g} fps" in capsys.readouterr().out
    assert _count(out) == expected
    first = next(e for e in traj.events if e.get("impact"))
    k = round(_video_time(events, first["t"]) * FPS)
    # the layout the frames were drawn with (the same call, into a throwaway GIF)
    info = video.write_video(traj, tmp_path / "layout.gif", fps=FPS, speed=SPEED, slow=SLOW, window=WINDOW)
    assert info["times"][k] == first["t"]  # the event's own instant is a frame
    at, before = _decode(out, k), _decode(out, k - 1)
    from pcmm.viz.draw2d import Sketch
    scale = Sketch(traj).arrow_scale
    p0 = np.array(first["contact_point"][:2])
    tip = p0 + scale * np.array(first["impulse"]["vector"][:2])
    pts = [video.pixel_of(info, *(p0 + s * (tip - p0))) for s in np.linspace(0.5, 0.8, 7)]

    def red(img, x, y):
        patch = img[y - 1:y + 2, x - 1:x + 2]
        return bool(((patch[..., 0] > 150) & (patch[..., 1] < 80) & (patch[..., 2] < 80)).any())
    assert sum(red(at, x, y) for x, y in pts) >= 6, "no impulse arrow at the first impact"
    assert sum(red(before, x, y) for x, y in pts) == 0, "an arrow a frame before the impact"


def test_a_video_of_another_kind_is_refused_by_name(run, tmp_path, capsys):
    assert main(["replay", str(run[0]), "--video", str(tmp_path / "run.avi")]) != 0
    assert "run.avi: a video is written as .mp4 or .gif, not '.avi'" in capsys.readouterr().err
