"""URDF reading and validation cost against the number of links (docs/limits.md).

    python benchmarks/urdf_validation.py

Reads serial chains of 1,000 to 8,000 links through ``pcmm.scene.urdf.read_urdf`` (parse, validate,
build nothing), interleaved repetitions, median per size.  Linear validation gives 8x from
1,000 to 8,000 links, quadratic 64x.  (This was a timed unit test once; ratios belong here.)
"""
from __future__ import annotations

import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from builders import bar_xml, joint_xml, link_xml, robot_xml  # noqa: E402

from pcmm.scene.urdf import read_urdf  # noqa: E402

SIZES = (1000, 2000, 4000, 8000)


def chain(folder: Path, n: int) -> Path:
    parts, prev = [link_xml("frame")], "frame"
    for i in range(n):
        parts += [bar_xml(f"l{i}", 0.1, 1.0), joint_xml(f"j{i}", "revolute", prev, f"l{i}", xyz=(0.1, 0))]
        prev = f"l{i}"
    path = folder / f"chain{n}.urdf"
    path.write_text(robot_xml("chain", *parts))
    return path


def main(repeats: int = 5) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        paths = {n: chain(Path(tmp), n) for n in SIZES}
        times = {n: [] for n in SIZES}
        for _ in range(repeats):
            for n in SIZES:
                t = time.perf_counter()
                read_urdf(paths[n])
                times[n].append(time.perf_counter() - t)
    med = {n: statistics.median(v) for n, v in times.items()}
    for n in SIZES:
        print(f"{n:5d} links: {med[n] * 1e3:8.1f} ms  ({med[n] / med[SIZES[0]]:.1f}x the {SIZES[0]}-link chain)")
    print(f"8x the links cost {med[SIZES[-1]] / med[SIZES[0]]:.1f}x (linear 8x, quadratic 64x)")


if __name__ == "__main__":
    main()
