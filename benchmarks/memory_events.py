"""Memory a bouncing run retains per event and per sample (issue 26, item 5).

    python benchmarks/memory_events.py                 # 1,000 and 3,000 bounces
    python benchmarks/memory_events.py 10000 30000     # longer runs

The scene is a ball on a vertical prismatic joint above a floor (restitution e = 1, so it never
accumulates: every bounce is one event and one segment), written to a temporary folder.  Each
run length is simulated in a subprocess of its own under ``tracemalloc`` (after a short warm-up
run there, so models and modules are not counted); the difference between the two lengths
divided by the difference in events (and in samples) is what the run retains per event (and per
sample), free of the constant start-up cost.  Each subprocess also reports its peak RSS.
"""
from __future__ import annotations

import math
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import traced_run_in_child  # noqa: E402

G = 9.81
H = 1.0
PERIOD = 2.0 * math.sqrt(2.0 * H / G)  # one bounce to the next

BALL = """<robot name="{name}"><link name="frame"/>
<joint name="Y" type="{jtype}"><parent link="frame"/><child link="ball"/><origin xyz="0 0 0"/>{axis}</joint>
<link name="ball"><inertial><mass value="1.0"/><origin xyz="0 0 0"/>
<inertia ixx="0.001" iyy="0.001" izz="0.001" ixy="0" ixz="0" iyz="0"/></inertial></link></robot>
"""

SCENE = """[scene]
name = "bouncing_ball"
gravity = [0.0, -9.81]
t_end = {t_end!r}
initial_configuration = "free"

[solver]
max_events = 100000000

[configurations.free]
urdf = "free.urdf"

[configurations.rest]
urdf = "rest.urdf"

[initial]
q = {{ Y = {h!r} }}
v = {{ Y = 0.0 }}

[[transitions]]
name = "floor"
type = "stop"
from = "free"
restitution = 1.0
merge_to = "rest"
cut = []
guard = {{ type = "gap", value = 0.0, direction = "decreasing" }}
contact = {{ a = "frame", point_a = [0.0, 0.0], b = "ball", point_b = [0.0, 0.0], normal = [0.0, 1.0] }}
"""

def write_scene(folder: Path, t_end: float) -> Path:
    (folder / "free.urdf").write_text(BALL.format(name="ball", jtype="prismatic", axis='<axis xyz="0 1 0"/><limit lower="-1e3" upper="1e3" effort="1e3" velocity="1e3"/>'))
    (folder / "rest.urdf").write_text(BALL.format(name="ball_rest", jtype="fixed", axis=""))
    path = folder / "bouncing_ball.toml"
    path.write_text(SCENE.format(t_end=t_end, h=H))
    return path


def measure(path: Path, bounces: int) -> dict:
    t_end = (bounces - 0.5) * PERIOD + 0.5 * PERIOD  # the first impact at PERIOD/2, then one per PERIOD
    return traced_run_in_child(path, t_end)


def main(short: int = 1000, long: int = 3000) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = write_scene(Path(tmp), 1.0)
        a, b = measure(path, short), measure(path, long)
    for r in (a, b):
        print(f"{r['events']:>8} events, {r['samples']:>8} samples, {r['segments']:>8} segments: retained "
              f"{r['retained'] / 1e6:8.2f} MB, traced peak {r['peak'] / 1e6:8.2f} MB, peak RSS {r['rss_peak_kb'] / 1e3:7.1f} MB")
    de, ds = b["events"] - a["events"], b["samples"] - a["samples"]
    dr = b["retained"] - a["retained"]
    print(f"retained per event (with its segment and samples): {dr / de:.0f} B; "
          f"{b['samples'] / b['events']:.1f} samples per event")
    print(f"retained per sample (all of it charged to samples): {dr / ds:.0f} B")


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:3]))
