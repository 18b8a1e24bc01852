"""After a release, a stop's guard that only moves away reports no "closest approach".

closest_approach read the first sample after the release (the freed joint an ulp from its stop) as
the guard's nearest point: "closest -1.48353562 at t = 1.11152 s, 5.76e-06 short", a near miss
to the eye, while the loop swings monotonically away from the stop.  A closest approach is now
reported only where the distance has a minimum inside the run (the rate turned back towards the
value), or at the run's end while it approaches again; otherwise the record says the measure moved
away since the guard's last event, and where it is at the end.
"""
from __future__ import annotations

import math

import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

import pcmm
from pcmm.run.approach import describe
from test_newcomer2_mechanisms import (FOURBAR_TOML, FOURBAR_URDF, K_ARM, Q3_STOP, at_rest, dpotential,
                                       loop_rhs, q3_of)


def test_after_the_release_the_stop_guard_moved_away_and_is_no_near_miss(tmp_path):
    """The four-bar's merge is let go at t_r (statics); from rest there its own dynamics (the
    newcomer's KKT integration, independent of pcmm) take q3 = theta_rocker - theta_coupler from
    -85 deg down to q3(1.2 s): that is where the record says the measure ended, and q3 only fell."""
    (tmp_path / "fourbar.urdf").write_text(FOURBAR_URDF)
    (tmp_path / "fourbar.toml").write_text(FOURBAR_TOML)
    traj = pcmm.simulate(pcmm.load_scene(tmp_path / "fourbar.toml"))
    th1_stop = brentq(lambda x: q3_of(x) - Q3_STOP, math.radians(90), math.radians(180))
    t_r = math.sqrt((math.radians(140) - th1_stop - dpotential(th1_stop) / K_ARM) / 0.5)
    end = solve_ivp(loop_rhs, (t_r, 1.2), at_rest(th1_stop), rtol=1e-12, atol=1e-13, method="DOP853").y[:, -1]
    q3_end = end[2] - end[1]
    (rec,) = traj.stats["closest_approach"]
    assert rec["moved_away"] and rec["closest"] is None and rec["t"] is None and rec["distance"] is None
    assert rec["last_fired"] == pytest.approx(t_r, abs=1e-8)
    assert rec["t_final"] == 1.2 and rec["final"] == pytest.approx(q3_end, abs=1e-8)
    assert q3_end < Q3_STOP - 5e-3
    text = describe([rec])
    assert "moved away from its value and never turned back" in text and "short" not in text
    assert f"{abs(q3_end - Q3_STOP):.3g} from it" in text
