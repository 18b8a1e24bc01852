"""What a designer reads of a scene with pins and stick contacts, recomputed by another route
(task h-audit3: no silent wrong number).

Housner's rocking block (``tests/test_newcomer3_rocking.py``'s scene) is the reference: a single
rigid body pinned at a corner, so every series has a Newton-Euler form written here without pcmm:

* energies: T = m |v_c|^2 / 2 + I_c w^2 / 2, V = m g y_c (the block's origin is its centre);
* the corner's stance force F (on the block, world axes) from the 5 x 5 KKT system of the body
  pinned at r = corner - c: m a_c = F + m g, I_c alpha = r x F, a_c + alpha k x r - w^2 r = 0;
* ``stats.holding``: the extremes of F_n = F_y and F_t = F_x along the run (at or beyond the recorded
  samples'), each the KKT force at the dense output's state at its own time;
* at each strike: KE- and KE+ are the series' values on both sides; the impulse on the block is the
  change of its linear momentum (the released corner carries none), so |P| = m |v_c+ - v_c-|.

Then the ``--dt`` CSV (every column by hand at every row; rows at the recorded ends and at each
event, before and after; against runs stopped at a row's time), the run to T as the first part of
the run to 2 T, the study table's impulse columns (normal part, and the new magnitude columns) by
hand from Housner's closed form, the pinned leg's and the stick-Poisson cart's columns by their own
hand models, and `pcmm run --out x.csv` (it wrote an NPZ named .csv) refused.
"""
from __future__ import annotations

import csv
import math

import numpy as np
import pytest

import oracle
import test_newcomer2_mechanisms as nm
import test_newcomer3_rocking as rock
import test_stick_law as stick

import pcmm
import pcmm.cli
from builders import EXAMPLES
from pcmm.results.summary import summary
from pcmm.studies.job import QUANTITIES, quantities
from pcmm.studies.sweep import make_plan, parse_set, sweep

M, B, H, G = rock.M, rock.B, rock.H, rock.G
I_C = M * (4 * B * B + 4 * H * H) / 12
R_HOUSNER = 1 - 1.5 * math.sin(rock.ALPHA) ** 2
CORNER = {"on_right": (B, -H), "on_left": (-B, -H)}
PIN = {"on_right": "right", "on_left": "left"}


def write_block(folder, g=G):
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "block.urdf").write_text(rock.URDF)
    text = rock.SCENE.replace("gravity = [0.0, -9.81]", f"gravity = [0.0, {-g!r}]")
    assert text.count(f"gravity = [0.0, {-g!r}]") == 1
    (folder / "rocking.toml").write_text(text)
    return folder / "rocking.toml"


@pytest.fixture(scope="module")
def block(tmp_path_factory):
    path = write_block(tmp_path_factory.mktemp("audit3_block"))
    return path, pcmm.simulate(pcmm.load_scene(path))


def stance_force(theta, w, configuration, g=G):
    """The corner's force on the block (world axes), Newton-Euler's KKT solve."""
    bx, by = CORNER[configuration]
    c, s = math.cos(theta), math.sin(theta)
    r = np.array([c * bx - s * by, s * bx + c * by])
    A = np.array([[M, 0, 0, -1, 0], [0, M, 0, 0, -1], [0, 0, I_C, r[1], -r[0]],
                  [1, 0, -r[1], 0, 0], [0, 1, r[0], 0, 0]], float)
    return np.linalg.solve(A, [0.0, -M * g, 0.0, w * w * r[0], w * w * r[1]])[3:]


def check_held(traj, name, part, values, by_hand, rel=1e-2):
    """``stats.holding[name][part]`` against the hand's force: at or beyond the extremes of its values
    at the recorded samples (``values``), by at most ``rel`` of their size (the peak between steps),
    and each extreme the hand's force (``by_hand(record) -> the part at its samples``) at the dense
    output's state at the extreme's time (pcmm.results.peaks)."""
    held = traj.stats["holding"][name][part]
    scale = max(1.0, float(np.abs(values).max()))
    ulp = 1e-13 * scale  # (the hand's values and the record's differ by round-off)
    assert values.min() - rel * scale < held["min"] <= values.min() + ulp
    assert values.max() - ulp <= held["max"] < values.max() + rel * scale
    for key in ("min", "max"):
        t = held[f"t_{key}"]
        (seg,) = [s for s in traj.segments if s.t[0] <= t <= s.t[-1] and f"{name}.fx" in s.constraint_labels][:1]
        assert held[key] == pytest.approx(float(by_hand(seg.resampled(np.array([t])))[0]), abs=1e-11 * scale)


def test_block_series_by_newton_euler(block):
    _, traj = block
    samples = {}
    for s in traj.segments:
        q, v = np.asarray(s.q), np.asarray(s.v)
        ke = 0.5 * M * (v[:, 0] ** 2 + v[:, 1] ** 2) + 0.5 * I_C * v[:, 2] ** 2
        assert np.abs(ke - s.kinetic).max() < 1e-15
        assert np.abs(M * G * q[:, 1] - s.potential).max() < 1e-15
        assert np.ptp(s.kinetic + s.potential) < 1e-12  # no dissipation between strikes
        name = PIN[s.configuration]
        F = np.array([stance_force(th, w, s.configuration) for th, w in zip(q[:, 2], v[:, 2])])
        labels = list(s.constraint_labels)
        assert labels == [f"{name}.fx", f"{name}.fy"]
        assert np.abs(F - np.asarray(s.constraint_forces)).max() < 1e-13
        # and through the whole run's series (NaN where the other corner is pinned)
        got = samples.setdefault(name, [])
        got += [(t, f) for t, f in zip(s.t, F)]
    for name, rows in samples.items():
        t = np.array([r[0] for r in rows])
        F = np.array([r[1] for r in rows])
        for i, part in ((0, "tangential"), (1, "normal")):
            check_held(traj, name, part, F[:, i], lambda r, i=i: np.array(
                [stance_force(th, w, r.configuration) for th, w in zip(r.q[:, 2], r.v[:, 2])])[:, i])
        assert F[:, 1].min() > 8.4  # compression throughout: the pin holds
    fy = traj.series("constraint_forces", "right.fy")
    on_right = np.array([c == "on_right" for c in traj.configuration_at()])
    assert np.all(np.isnan(fy[~on_right])) and not np.any(np.isnan(fy[on_right]))


def test_block_strikes_energy_and_momentum(block):
    _, traj = block
    segs = list(traj.segments)
    assert len(traj.events) == 7
    for e, before, after in zip(traj.events, segs[:-1], segs[1:]):
        assert e["kinetic_energy_before"] == pytest.approx(before.kinetic[-1], abs=1e-15)
        assert e["kinetic_energy_after"] == pytest.approx(after.kinetic[0], abs=1e-15)
        lost = before.kinetic[-1] - after.kinetic[0]
        assert e["energy_dissipated"] == pytest.approx(lost, abs=1e-15)
        assert lost == pytest.approx((1 - R_HOUSNER ** 2) * before.kinetic[-1], rel=1e-9)
        vm, vp = np.asarray(before.v[-1]), np.asarray(after.v[0])
        P = M * (vp[:2] - vm[:2])  # the only impulse on the block: the new corner's
        assert e["impulse"]["vector"] == pytest.approx(P.tolist(), abs=1e-12)
        assert math.hypot(e["impulse"]["normal"], e["impulse"]["tangential"]) == pytest.approx(np.hypot(*P), rel=1e-12)
        # its tangential share, by Housner: P = m w (h (1 - r), +-b (1 + r)) about the upright block
        assert abs(P[0] / P[1]) == pytest.approx(H * (1 - R_HOUSNER) / (B * (1 + R_HOUSNER)), rel=1e-6)
        # momenta about the scene's point (the origin): L = m v_c, H_O = I_c w + c x m v_c
        mom = e["momentum"]
        assert mom["about"] == [0.0, 0.0]
        c = np.asarray(before.q[-1])[:2]
        for v, key in ((vm, "before"), (vp, "after")):
            assert mom[f"linear_{key}"] == pytest.approx((M * v[:2]).tolist(), abs=1e-13)
            assert mom[f"angular_{key}"] == pytest.approx(I_C * v[2] + M * (c[0] * v[1] - c[1] * v[0]), abs=1e-13)
        corner = np.asarray(e["anchor"][PIN[after.configuration]])
        turn = (corner[0] * P[1] - corner[1] * P[0])  # the impulse's moment about the origin
        assert mom["angular_after"] - mom["angular_before"] == pytest.approx(turn, abs=1e-13)


def read_csv(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_block_dt_csv_by_hand(block, tmp_path):
    path, traj = block
    out = tmp_path / "block.csv"
    assert pcmm.cli.main(["run", str(path), "--dt", "0.01", "--csv", str(out), "--quiet"]) == 0
    rows = read_csv(out)
    head = list(rows[0])
    assert head[:2] == ["t [s]", "configuration"]
    for col in ("q_base.x [m]", "v_base.x [m/s in world axes]", "q_base.theta [rad]", "v_base.theta [rad/s]",
                "constraint_right.fx [N]", "constraint_left.fy [N]", "kinetic_energy [J]", "potential_energy [J]"):
        assert col in head
    t = np.array([float(r["t [s]"]) for r in rows])
    assert np.all(np.diff(t) >= 0)
    # the grid, and every event twice: before in the old configuration, after in the new
    for e in traj.events:
        at = [r for r in rows if float(r["t [s]"]) == e["t"]]
        assert [r["configuration"] for r in at] == [e["from"], e["to"]]
        assert float(at[1]["kinetic_energy [J]"]) == pytest.approx(e["kinetic_energy_after"], abs=1e-15)
    grid = np.round(np.arange(0, 2.0 + 1e-9, 0.01), 12)
    assert set(grid) <= set(np.round(t, 12))
    worst = 0.0
    for r in rows:
        f = {k: float(x) for k, x in r.items() if k != "configuration" and x != ""}
        cfg = r["configuration"]
        vx, vy, w = f["v_base.x [m/s in world axes]"], f["v_base.y [m/s in world axes]"], f["v_base.theta [rad/s]"]
        th = f["q_base.theta [rad]"]
        assert f["kinetic_energy [J]"] == pytest.approx(0.5 * M * (vx * vx + vy * vy) + 0.5 * I_C * w * w, abs=1e-14)
        assert f["potential_energy [J]"] == pytest.approx(M * G * f["q_base.y [m]"], abs=1e-14)
        F = stance_force(th, w, cfg)
        name, other = PIN[cfg], PIN["on_left" if cfg == "on_right" else "on_right"]
        assert (f[f"constraint_{name}.fx [N]"], f[f"constraint_{name}.fy [N]"]) == pytest.approx(tuple(F), abs=1e-12)
        assert r[f"constraint_{other}.fx [N]"] == ""
        bx, by = CORNER[cfg]  # the pinned corner stays on the floor between the samples too
        worst = max(worst, abs(f["q_base.y [m]"] + math.sin(th) * bx + math.cos(th) * by))
        # energy: the series' total is the last strike's
        assert (f["theta_block [rad]"], f["x_block [m]"], f["y_block [m]"]) == (th, f["q_base.x [m]"], f["q_base.y [m]"])
    assert worst < 1e-12
    # the resampled rows are the dense solution: runs stopped at two rows' instants
    scene = pcmm.load_scene(path)
    for i in (57, 163):
        r = rows[i]
        end = pcmm.simulate(scene, pcmm.RunOptions(t_end=float(r["t [s]"]))).segments[-1]
        assert end.configuration == r["configuration"]
        got = [float(r[k]) for k in ("q_base.x [m]", "q_base.y [m]", "q_base.theta [rad]", "v_base.theta [rad/s]")]
        want = [*np.asarray(end.q[-1]), float(np.asarray(end.v[-1])[2])]
        assert got == pytest.approx(want, abs=1e-9)


def test_block_run_to_t_is_the_first_part_of_the_run_to_2t(block):
    path, long = block  # t_end = 2.0
    short = pcmm.simulate(pcmm.load_scene(path), pcmm.RunOptions(t_end=1.0))
    n = len(short.events)
    assert n >= 2 and [e["t"] for e in short.events] == [e["t"] for e in long.events[:n]]
    assert [e["impulse"] for e in short.events] == [e["impulse"] for e in long.events[:n]]
    k = len(short.t) - 1  # the short run's last sample is its t_end, not a step of the long run
    assert np.array_equal(short.t[:k], long.t[:k]) and short.t[k] == 1.0
    for quantity, name in (("kinetic", None), ("potential", None), ("q", "base.theta"), ("constraint_forces", "left.fy")):
        a, b = short.series(quantity, name)[:k], long.series(quantity, name)[:k]
        assert np.array_equal(np.isnan(a), np.isnan(b)) and np.array_equal(a[~np.isnan(a)], b[~np.isnan(b)])
    assert short.stats["holding"]["right"]["normal"]["max"] == long.stats["holding"]["right"]["normal"]["max"]


def housner_impulses(g, strikes):
    """(P_n, |P|) of the first ``strikes`` strikes, by hand: the first at the rate of the fall from
    the tilt, each next one r times the last (P = m w (h (1 - r), b (1 + r)) in magnitude)."""
    w = math.sqrt(2 * M * g * rock.R * (math.cos(rock.ALPHA - rock.TILT) - math.cos(rock.ALPHA)) / rock.I_O)
    out = []
    for _ in range(strikes):
        Pn, Pt = M * w * B * (1 + R_HOUSNER), M * w * H * (1 - R_HOUSNER)
        out.append((Pn, math.hypot(Pn, Pt)))
        w *= R_HOUSNER
    return out


def test_study_impulse_columns_normal_and_magnitude_by_hand(tmp_path):
    """A sweep of gravity (9.81, 6.0 m/s^2) over the block to 1 s: ``first_impulse`` etc. are the
    normal parts P_n, and ``*_impulse_magnitude`` the 2-D |P| (2.9 % more here), both by
    Housner's closed form; the energy columns equal the strikes' KE- - KE+."""
    path = write_block(tmp_path / "base")
    res = sweep(pcmm.load_scene(path), make_plan([parse_set("scene.gravity[1]=-9.81,-6.0")]), tmp_path / "t.csv",
                pcmm.RunOptions(t_end=1.0), workers=1)
    rows = read_csv(tmp_path / "t.csv")
    assert res.status == {"complete": 2}
    for row in rows:
        g = -float(row["scene.gravity[1]"])
        traj = pcmm.simulate(pcmm.load_scene(write_block(tmp_path / f"g{g}", g)), pcmm.RunOptions(t_end=1.0))
        n = len(traj.events)
        assert int(row["impacts"]) == n >= 2
        hand = housner_impulses(g, n)
        assert float(row["first_impulse"]) == pytest.approx(hand[0][0], rel=1e-8)
        assert float(row["peak_impulse"]) == pytest.approx(hand[0][0], rel=1e-8)
        assert float(row["total_impulse"]) == pytest.approx(math.fsum(p for p, _ in hand), rel=1e-8)
        assert float(row["first_impulse_magnitude"]) == pytest.approx(hand[0][1], rel=1e-8)
        assert float(row["peak_impulse_magnitude"]) == pytest.approx(hand[0][1], rel=1e-8)
        assert float(row["total_impulse_magnitude"]) == pytest.approx(math.fsum(m for _, m in hand), rel=1e-8)
        assert float(row["first_impulse_magnitude"]) / float(row["first_impulse"]) == pytest.approx(1.0291, abs=1e-4)
        segs = list(traj.segments)
        lost = math.fsum(b.kinetic[-1] - a.kinetic[0] for b, a in zip(segs[:-1], segs[1:]))
        assert float(row["kinetic_energy_lost"]) == pytest.approx(lost, rel=1e-12)
        assert float(row["energy_dissipated"]) == pytest.approx(lost, rel=1e-12)
        # the corner's holding force is a pin's stance force, not a lock's: not in max_holding_force
        assert row["max_holding_force"] == ""


def test_the_help_names_the_normal_part_and_the_magnitude(capsys):
    """`pcmm sweep -h` listed no column: what `peak_impulse` holds was in docs/cli.md alone, which
    said "of |P|" (it is |P_n|)."""
    assert "normal part only" in QUANTITIES["peak_impulse"] and "normal part only" in QUANTITIES["total_impulse"]
    # the figures' titles are the text before the first ';' (pcmm/studies/plots.py): whole phrases
    for name, text in QUANTITIES.items():
        title = text.split(";")[0]
        assert title.count("(") == title.count(")"), name
    assert "sqrt(P_n^2 + P_t^2)" in QUANTITIES["peak_impulse_magnitude"]
    with pytest.raises(SystemExit):
        pcmm.cli.main(["sweep", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for name in QUANTITIES:
        assert f" {name}: " in text
    assert "peak_impulse: largest |normal impulse P_n| at one contact over the run, N s; the normal part only" in text
    assert "peak_impulse_magnitude: largest |P| = sqrt(P_n^2 + P_t^2) at one contact over the run, N s" in text


def test_leg_pin_columns_by_its_lagrangian(tmp_path):
    """The pinned leg (friction 0.6 but the pin takes any tangential impulse): first_impulse is the
    foot's normal impulse, the magnitude the whole 2-D one, P = -J^-T M w- by its Lagrangian; all
    the kinetic energy is lost; the stance force is the static J^-T dV/da (nothing moves)."""
    scene = nm.leg_scene(tmp_path, 60.0, 60.0, -0.7)
    traj = pcmm.simulate(scene, pcmm.RunOptions(t_end=0.6))
    t, y = nm.leg_strike(60.0, 60.0, -0.7, 0.0)
    P = nm.pin_impulse(*y)
    assert abs(P[0] / P[1]) > 0.1  # a large tangential share
    q = quantities(summary(traj, scene.initial_configuration))
    ke = 0.5 * y[2:] @ nm.leg_mass(y[0], y[1]) @ y[2:]
    assert q["impacts"] == 1 and q["first_impact_t"] == pytest.approx(t, abs=1e-9)
    assert q["first_impulse"] == pytest.approx(P[1], rel=1e-8)
    assert q["peak_impulse_magnitude"] == pytest.approx(float(np.hypot(*P)), rel=1e-8)
    assert q["total_impulse_magnitude"] == q["first_impulse_magnitude"] == q["peak_impulse_magnitude"]
    assert q["kinetic_energy_lost"] == pytest.approx(ke, rel=1e-8) and q["energy_dissipated"] == pytest.approx(ke, rel=1e-8)
    stance = traj.segments[-1]
    F = nm.stance_force(y[0], y[1])
    cf = np.asarray(stance.constraint_forces)
    assert cf[:, [stance.constraint_labels.index("foot.fx"), stance.constraint_labels.index("foot.fy")]] == \
        pytest.approx(np.tile(F, (len(stance.t), 1)), abs=1e-6)


def test_stick_poisson_cart_columns_by_hand(make_scene):
    """``friction = "stick"`` with Poisson's law (e = 0.5): the row's normal impulse, |P| and both
    energy columns against the no-slip impulse by hand (tests/test_stick_law.py's cart)."""
    path = stick.cart_scene(make_scene, "poisson", 0.5)
    scene = pcmm.load_scene(path)
    traj = pcmm.simulate(scene)
    ev, q, D, vm, (vt, vn) = stick.strike(traj)
    P, _, lost_t, lost_n = stick.by_hand(D, vt, vn, 0.5, "poisson")
    Mq = stick.mass_matrix(q)
    vp = vm + np.linalg.solve(Mq, stick.tip_rows(q).T @ P)
    lost = 0.5 * vm @ Mq @ vm - 0.5 * vp @ Mq @ vp
    assert lost == pytest.approx(lost_t + lost_n, rel=1e-12)
    row = quantities(summary(traj, scene.initial_configuration))
    assert row["impacts"] == 1
    assert row["first_impulse"] == pytest.approx(P[1], rel=1e-9)
    assert row["first_impulse_magnitude"] == pytest.approx(float(np.hypot(*P)), rel=1e-9)
    assert row["kinetic_energy_lost"] == pytest.approx(lost, rel=1e-9)
    assert row["energy_dissipated"] == pytest.approx(lost, rel=1e-9)
    segs = list(traj.segments)
    assert segs[0].kinetic[-1] - segs[1].kinetic[0] == pytest.approx(lost, rel=1e-9)


@pytest.mark.parametrize("flag,name,meant", [("--out", "x.csv", "--csv"), ("--csv", "x.npz", "--out"),
                                             ("--out", "x.json", "--summary")])
def test_run_output_named_for_another_format_is_refused(block, tmp_path, capsys, flag, name, meant):
    """`pcmm run --out x.csv` wrote the NPZ trajectory into x.csv, silently (exit 0): a spreadsheet
    then opens a zip file.  Now refused before the run, naming the flag that writes that format."""
    path, _ = block
    out = tmp_path / name
    assert pcmm.cli.main(["run", str(path), "--t-end", "0.01", flag, str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert f"{flag} {out}:" in err and f"give {meant} {out}" in err and not out.exists()


# ---- the rimless wheel and the compass gait: their pinned feet by a Lagrangian of their own ------
def rot(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s], [s, c]])


def cross_k(r):
    return np.array([-r[1], r[0]])


def pinned_force(masses, inertias, angles, rates, g):
    """The pin's force on a mechanism of point masses hung from it by rigid arms: each mass at
    anchor + sum_k R(angle_k) u_k.  Lagrange in the absolute angles (M a'' = Q_g - centripetal),
    then F = sum m_i a_i - sum m_i g."""
    n = len(angles)
    Mq, Q, b = np.zeros((n, n)), np.zeros(n), np.zeros(n)
    for m, terms in masses:
        J, centripetal = np.zeros((2, n)), np.zeros(2)
        for k, u in terms:
            r = rot(angles[k]) @ u
            J[:, k] += cross_k(r)
            centripetal -= rates[k] ** 2 * r
        Mq += m * J.T @ J
        Q += m * J.T @ g
        b += m * J.T @ centripetal
    for k, inertia in inertias.items():
        Mq[k, k] += inertia
    acc = np.linalg.solve(Mq, Q - b)
    F = np.zeros(2)
    for m, terms in masses:
        a = sum(acc[k] * cross_k(rot(angles[k]) @ u) - rates[k] ** 2 * (rot(angles[k]) @ u) for k, u in terms)
        F += m * a - m * g
    return F


WHEEL_G = np.array([9.81 * math.sin(0.2), -9.81 * math.cos(0.2)])
GAIT_G = np.array([9.81 * math.sin(0.0525), -9.81 * math.cos(0.0525)])


def wheel_by_hand(configuration, q, v):
    """(KE, PE, the foot's force, its cut joint) of McGeer's wheel (hub 1 kg, I = 0.05) on spoke k."""
    k = int(configuration[len("spoke"):])
    tip = np.array([math.sin(k * math.pi / 3), -math.cos(k * math.pi / 3)])
    hub, vh, th, w = np.array([q["hub.x"], q["hub.y"]]), np.array([v["hub.x"], v["hub.y"]]), q["hub.theta"], v["hub.theta"]
    F = pinned_force([(1.0, [(0, -tip)])], {0: 0.05}, [th], [w], WHEEL_G)
    return 0.5 * vh @ vh + 0.5 * 0.05 * w * w, -float(WHEEL_G @ hub), F, f"foot{k}"


def gait_by_hand(configuration, q, v):
    """(KE, PE, the stance foot's force, its cut joint) of the compass gait: 10 kg at the hip, 5 kg
    halfway down each 1 m leg (leg_a at psi_a = base.theta, leg_b at psi_b = psi_a + hip)."""
    hip, vh = np.array([q["base.x"], q["base.y"]]), np.array([v["base.x"], v["base.y"]])
    pa, wa = q["base.theta"], v["base.theta"]
    pb, wb = pa + q["hip"], wa + v["hip"]
    ra, rb = rot(pa) @ [0.0, -0.5], rot(pb) @ [0.0, -0.5]
    va, vb = vh + wa * cross_k(ra), vh + wb * cross_k(rb)
    ke = 0.5 * 10 * vh @ vh + 0.5 * 5 * va @ va + 0.5 * 5 * vb @ vb
    pe = -float((10 * hip + 5 * (hip + ra) + 5 * (hip + rb)) @ GAIT_G)
    up, half, down = np.array([0.0, 1.0]), np.array([0.0, 0.5]), np.array([0.0, -0.5])
    s, w = (0, 1) if configuration == "stance_a" else (1, 0)  # the stance leg's angle, the swing leg's
    F = pinned_force([(10, [(s, up)]), (5, [(s, half)]), (5, [(s, up), (w, down)])], {}, [pa, pb], [wa, wb], GAIT_G)
    return ke, pe, F, "foot_a" if configuration == "stance_a" else "foot_b"


WALKERS = {"rimless_wheel": (wheel_by_hand, 3.0, 3), "compass_gait": (gait_by_hand, 2.0, 2)}


@pytest.fixture(scope="module", params=list(WALKERS))
def walker(request, tmp_path_factory):
    name = request.param
    hand, t_end, strikes = WALKERS[name]
    path = EXAMPLES / f"{name}.toml"
    traj = pcmm.simulate(pcmm.load_scene(path), pcmm.RunOptions(t_end=t_end))
    assert len(traj.events) == strikes
    out = tmp_path_factory.mktemp(name) / "run.csv"
    assert pcmm.cli.main(["run", str(path), "--t-end", str(t_end), "--dt", "0.01", "--csv", str(out), "--quiet"]) == 0
    return name, path, hand, traj, read_csv(out)


def test_walker_series_and_holding_by_hand(walker):
    """Every recorded sample: the energies and the stance foot's force by the walker's own
    Lagrangian; ``stats.holding``'s extremes are those of the hand's forces; each strike's KE- and
    KE+ are the series' on both sides and its energy_dissipated their difference."""
    _, _, hand, traj, _ = walker
    forces = {}
    for s in traj.segments:
        q, v, cf, labels = np.asarray(s.q), np.asarray(s.v), np.asarray(s.constraint_forces), list(s.constraint_labels)
        for i, t in enumerate(s.t):
            ke, pe, F, foot = hand(s.configuration, dict(zip(s.coordinates, q[i])), dict(zip(s.coordinates, v[i])))
            assert (s.kinetic[i], s.potential[i]) == pytest.approx((ke, pe), abs=1e-12)
            got = cf[i, [labels.index(f"{foot}.fx"), labels.index(f"{foot}.fy")]]
            assert got == pytest.approx(F, abs=1e-11 * max(1.0, abs(F[1])))
            forces.setdefault(foot, []).append((t, F))
    for foot, rows in forces.items():
        t, F = np.array([r[0] for r in rows]), np.array([r[1] for r in rows])
        for i, part in ((0, "tangential"), (1, "normal")):
            check_held(traj, foot, part, F[:, i], lambda r, i=i: [
                hand(r.configuration, dict(zip(r.coordinates, r.q[0])), dict(zip(r.coordinates, r.v[0])))[2][i]])
        assert F[:, 1].min() > 0  # compression: the pin holds
    segs = list(traj.segments)
    for e, before, after in zip(traj.events, segs[:-1], segs[1:]):
        assert (e["kinetic_energy_before"], e["kinetic_energy_after"]) == \
            pytest.approx((before.kinetic[-1], after.kinetic[0]), rel=1e-13)  # two routes: M(q) v, the series'
        assert e["energy_dissipated"] == pytest.approx(before.kinetic[-1] - after.kinetic[0], rel=1e-12)


def test_walker_dt_csv_by_hand(walker):
    """The ``--dt 0.01`` CSV: every row's energies and stance force by hand from its own q, v; the
    grid's instants and each strike twice (before, in the old stance; after, in the new)."""
    _, _, hand, traj, rows = walker
    for e in traj.events:
        at = [r for r in rows if float(r["t [s]"]) == e["t"]]
        assert [r["configuration"] for r in at] == [e["from"], e["to"]]
    t = np.array([float(r["t [s]"]) for r in rows])
    assert np.all(np.diff(t) >= 0) and set(np.round(np.arange(0, t[-1] + 1e-9, 0.01), 12)) <= set(np.round(t, 12))
    for r in rows:
        q = {k[2:].split(" [")[0]: float(x) for k, x in r.items() if k.startswith("q_")}
        v = {k[2:].split(" [")[0]: float(x) for k, x in r.items() if k.startswith("v_")}
        ke, pe, F, foot = hand(r["configuration"], q, v)
        assert (float(r["kinetic_energy [J]"]), float(r["potential_energy [J]"])) == pytest.approx((ke, pe), abs=1e-12)
        got = (float(r[f"constraint_{foot}.fx [N]"]), float(r[f"constraint_{foot}.fy [N]"]))
        assert got == pytest.approx(tuple(F), abs=1e-11 * max(1.0, abs(F[1])))
        others = [k for k in r if k.startswith("constraint_") and not k.startswith(f"constraint_{foot}.")]
        assert all(r[k] == "" for k in others)
    # a resampled row between two steps is the solution there: the run stopped at its instant
    _, path, _, _, _ = walker
    for r in (rows[len(rows) // 3], rows[2 * len(rows) // 3]):
        end = pcmm.simulate(pcmm.load_scene(path), pcmm.RunOptions(t_end=float(r["t [s]"]))).segments[-1]
        assert end.configuration == r["configuration"]
        for name, q, v in zip(end.coordinates, np.asarray(end.q[-1]), np.asarray(end.v[-1])):
            (qk,) = [k for k in r if k.startswith(f"q_{name} [")]
            (vk,) = [k for k in r if k.startswith(f"v_{name} [")]
            assert (float(r[qk]), float(r[vk])) == pytest.approx((q, v), abs=1e-9)


def test_walker_run_to_t_is_the_first_part_of_the_run_to_2t(walker):
    _, path, _, long, _ = walker
    T = float(long.t[-1]) / 2
    short = pcmm.simulate(pcmm.load_scene(path), pcmm.RunOptions(t_end=T))
    n, k = len(short.events), len(short.t) - 1
    assert n >= 1 and [e["t"] for e in short.events] == [e["t"] for e in long.events[:n]]
    assert [e["impulse"] for e in short.events] == [e["impulse"] for e in long.events[:n]]
    assert np.array_equal(short.t[:k], long.t[:k]) and short.t[k] == T
    for quantity in ("kinetic", "potential"):
        assert np.array_equal(short.series(quantity)[:k], long.series(quantity)[:k])


def test_block_on_a_tilted_floor_projects_on_its_normal(tmp_path):
    """The floor's normal n = (-sin 0.1, cos 0.1) (not the world's y): ``stats.holding``'s parts are
    F . n and F . t with t = (n_y, -n_x), F by the KKT solve; the strike's P_n, P_t are P . n, P . t
    with P = m (v_c+ - v_c-).  (Past 0.946 s the block, rocking on its lower corner, would need a
    tensile pin and the run stops there, naming the cut joint.)"""
    beta, th0 = 0.1, 0.1 - 0.2
    n = np.array([-math.sin(beta), math.cos(beta)])
    t_axis = np.array([n[1], -n[0]])
    text = rock.SCENE.replace("normal = [0.0, 1.0]", f"normal = [{float(n[0])!r}, {float(n[1])!r}]").replace(
        '"-(0.1*cos(-0.2) + 0.3*sin(-0.2))", "-(0.1*sin(-0.2) - 0.3*cos(-0.2))", -0.2]',
        f'"-(0.1*cos({th0!r}) + 0.3*sin({th0!r}))", "-(0.1*sin({th0!r}) - 0.3*cos({th0!r}))", {th0!r}]')
    assert text.count(f"normal = [{float(n[0])!r}, {float(n[1])!r}]") == 4 and "-0.2]" not in text
    (tmp_path / "block.urdf").write_text(rock.URDF)
    (tmp_path / "tilted.toml").write_text(text)
    traj = pcmm.simulate(pcmm.load_scene(tmp_path / "tilted.toml"), pcmm.RunOptions(t_end=0.94))
    assert [e["name"] for e in traj.events] == ["left strikes"]
    parts = {}
    for s in traj.segments:
        q, v = np.asarray(s.q), np.asarray(s.v)
        F = np.array([stance_force(th, w, s.configuration) for th, w in zip(q[:, 2], v[:, 2])])
        name = PIN[s.configuration]
        assert np.abs(F - np.asarray(s.constraint_forces)).max() < 1e-13  # NAME.fx, NAME.fy: world axes
        parts.setdefault(name, []).extend(zip(F @ n, F @ t_axis))
    for name, rows in parts.items():
        a = np.array(rows)
        for i, part in enumerate(("normal", "tangential")):
            check_held(traj, name, part, a[:, i], lambda r, i=i: [
                stance_force(r.q[0, 2], r.v[0, 2], r.configuration) @ (n, t_axis)[i]])
    assert 0 < parts["left"][-1][0] < 0.3  # the normal force nearly gone where the run ends
    e, (before, after) = traj.events[0], list(traj.segments)
    P = M * (np.asarray(after.v[0])[:2] - np.asarray(before.v[-1])[:2])
    assert (e["impulse"]["normal"], e["impulse"]["tangential"]) == pytest.approx((P @ n, P @ t_axis), abs=1e-13)
    assert e["impulse"]["vector"] == pytest.approx(P.tolist(), abs=1e-13)


def cart_by_hand(row: dict):
    """(KE, the tip's height) of tests/test_stick_law.py's cart at a CSV row."""
    q, v = np.array([float(row["q_X [m]"]), float(row["q_J1 [rad]"])]), \
        np.array([float(row["v_X [m/s]"]), float(row["v_J1 [rad/s]"])])
    return 0.5 * v @ stick.mass_matrix(q[1]) @ v, stick.L * math.sin(q[1])


def test_stick_poisson_cart_sweep_csv_and_prefix(make_scene, tmp_path):
    """The stick-Poisson stop (a bounce: no switch of configuration) in a sweep of its restitution
    (0.3, 0.7): each row's impulse columns and energies by hand; the ``--dt`` CSV of the e = 0.7 run
    has the bounce twice (KE- then KE+, both by hand) and its kinetic energy by hand at every row;
    the run to 6 ms is the first part of the run to 12 ms."""
    path = stick.cart_scene(make_scene, "poisson", 0.5)
    out = tmp_path / "e.csv"
    res = sweep(pcmm.load_scene(path), make_plan([parse_set("transitions.tip strikes floor.restitution=0.3,0.7")]),
                out, pcmm.RunOptions(t_end=0.006), workers=1)
    assert res.status == {"complete": 2}
    for row in read_csv(out):
        e = float(row["transitions.tip strikes floor.restitution"])
        traj = pcmm.simulate(pcmm.load_scene(stick.cart_scene(make_scene, "poisson", e)))
        ev, q, D, vm, (vt, vn) = stick.strike(traj)
        P, vn_after, lost_t, lost_n = stick.by_hand(D, vt, vn, e, "poisson")
        assert vn_after == pytest.approx(-e * (vn - D[0, 1] * vt / D[0, 0]), rel=1e-12)
        assert int(row["impacts"]) == 1
        assert float(row["first_impulse"]) == pytest.approx(P[1], rel=1e-9)
        assert float(row["peak_impulse_magnitude"]) == pytest.approx(float(np.hypot(*P)), rel=1e-9)
        assert float(row["kinetic_energy_lost"]) == pytest.approx(lost_t + lost_n, rel=1e-9)
        assert float(row["energy_dissipated"]) == pytest.approx(lost_t + lost_n, rel=1e-9)
    scene = stick.cart_scene(make_scene, "poisson", 0.7)
    csv_path = tmp_path / "cart.csv"
    assert pcmm.cli.main(["run", str(scene), "--dt", "0.001", "--csv", str(csv_path), "--quiet"]) == 0
    rows = read_csv(csv_path)
    traj = pcmm.simulate(pcmm.load_scene(scene))
    ev = traj.events[0]
    at = [r for r in rows if float(r["t [s]"]) == ev["t"]]
    assert len(at) == 2 and {r["configuration"] for r in at} == {"c1"}
    assert [cart_by_hand(r)[0] for r in at] == pytest.approx([ev["kinetic_energy_before"], ev["kinetic_energy_after"]],
                                                             rel=1e-12)
    for r in rows:
        ke, tip = cart_by_hand(r)
        assert float(r["kinetic_energy [J]"]) == pytest.approx(ke, rel=1e-12)
        assert tip >= stick.L * math.sin(stick.Q0) - stick.GAP - 1e-12  # never below the floor
    # a run this short takes its first step capped by t_end, so the steps (not the solution) differ:
    # the bounce 1.5e-16 s apart; the oracle's prefix check holds it to the dense output
    longer = pcmm.simulate(pcmm.load_scene(scene), pcmm.RunOptions(t_end=0.012))
    assert longer.events[0]["t"] == pytest.approx(ev["t"], abs=1e-15)
    (tmp_path / "prefix").mkdir()
    assert oracle.check_prefix(scene, 0.006, 0.012, 0.001, tmp_path / "prefix") == []


def test_contacts_closed_at_once_count_each_contact(make_scene, tmp_path):
    """A rod landing flat on both ends at once (tests/test_simultaneous.py: its end B approaching
    at 3.06 m/s, A at 0.34 m/s; e = 0.5, both sliding at mu = mu_c / 2): one event, whose own
    ``impulse`` is A's alone.  The table summed that one (1.2155 N s of the 3.3150 N s) and called
    A's the peak while B took 2.0995 N s.  By the closed forms of the mode enumeration: the total
    is P_nA + P_nB, the peak B's, the magnitudes sqrt(P_n^2 + (mu P_n)^2) per end."""
    import test_simultaneous as ts
    k, UA, UB, e = 3.0, -0.2 * ts.V, -1.8 * ts.V, 0.5
    mu = 0.5 * ts.by_hand(k, UA, UB, e, None)[-1]
    PtA, PnA, PtB, PnB, *_ = ts.by_hand(k, UA, UB, e, mu)
    assert 0 < PnA < PnB and (PtA, PtB) == pytest.approx((-mu * PnA, -mu * PnB), rel=1e-15)
    path = ts.rod_run(make_scene, k, UA, UB, e, mu)
    res = sweep(pcmm.load_scene(path), make_plan([parse_set("transitions.A.restitution=0.5"),
                                                  parse_set("transitions.B.restitution=0.5")]),
                tmp_path / "rod.csv", None, workers=1)
    assert res.status == {"complete": 1}
    (row,) = read_csv(tmp_path / "rod.csv")
    traj = pcmm.simulate(pcmm.load_scene(path))
    (ev,) = traj.events
    assert set(ev["simultaneous"]) == {"A", "B"} and ev["impulse"]["normal"] == pytest.approx(PnA, rel=1e-9)
    assert row["impacts"] == "1"
    assert float(row["first_impulse"]) == pytest.approx(PnA, rel=1e-9)  # the event's P: A's, the first contact
    assert float(row["peak_impulse"]) == pytest.approx(PnB, rel=1e-9)
    assert float(row["total_impulse"]) == pytest.approx(PnA + PnB, rel=1e-9)
    assert float(row["peak_impulse_magnitude"]) == pytest.approx(math.hypot(PtB, PnB), rel=1e-9)
    assert float(row["total_impulse_magnitude"]) == pytest.approx(math.hypot(PtA, PnA) + math.hypot(PtB, PnB), rel=1e-9)
    # the energy columns: the whole rod's KE- - KE+, by hand from the impulses' changes of momentum
    w0 = (UB - UA) / (2 * ts.A_)
    inertia = ts.M * ts.A_ ** 2 / k
    vg0 = np.array([ts.U, (UA + UB) / 2])  # G's velocity: the ends' normal velocities are v_gy -+ a w0
    vg1 = vg0 + np.array([PtA + PtB, PnA + PnB]) / ts.M
    w1 = w0 + ts.A_ * (PnB - PnA) / inertia
    lost = 0.5 * ts.M * (vg0 @ vg0 - vg1 @ vg1) + 0.5 * inertia * (w0 * w0 - w1 * w1)
    assert float(row["kinetic_energy_lost"]) == pytest.approx(lost, rel=1e-9)
    assert float(row["energy_dissipated"]) == pytest.approx(lost, rel=1e-9)


@pytest.mark.parametrize("both", [True, False])
def test_event_table_names_the_other_contacts_closed_at_once(make_scene, both):
    """`pcmm run`'s event table gives one row per event, whose vn and P are its first contact's: the
    rod's row said A's 1.2155 N s and nothing of B's 2.0995 N s.  Now the row names B with its impulse
    (by the closed forms), or says that B separates, with its speed away."""
    import test_simultaneous as ts
    from pcmm.results.summary import event_table
    k, UA, UB, e = (3.0, -0.2 * ts.V, -1.8 * ts.V, 0.5) if both else (0.5, -1.8 * ts.V, -0.2 * ts.V, 0.5)
    mu = 0.5 * ts.by_hand(k, UA, UB, e, None)[-1]
    PtA, PnA, PtB, PnB, _, UA1, UB1, _ = ts.by_hand(k, UA, UB, e, mu)
    (row,) = event_table(pcmm.simulate(pcmm.load_scene(ts.rod_run(make_scene, k, UA, UB, e, mu)))).splitlines()[2:]
    if both:
        assert f"at once: B P_n {PnB:.4e} P_t {PtB:.4e} N s (vn, P: A's alone)" in row
        assert f" {PnA:.4e} " in row
    else:
        assert PnB == 0.0 and f"at once: B separates (vn+ {UB1:.4e} m/s) (vn, P: A's alone)" in row


def test_a_table_from_before_the_magnitude_columns_resumes(tmp_path):
    """A sweep table written before the three magnitude columns (the shipped
    docs/figures/design_study/cycle_opt.csv, which examples/studies/cycle_design.py resumes) was
    refused on --resume as "not this study's" columns.  Its rows are now read into the new columns
    with those cells empty (their runs are not run again: nothing invents their values), the table
    rewritten with valid checksums and the warning naming the columns; a row cut short is dropped
    as before; any other difference of columns is still refused."""
    from pcmm.studies.table import checksum
    path = write_block(tmp_path / "base")
    out = tmp_path / "t.csv"
    plan = make_plan([parse_set("scene.gravity[1]=-9.81")])
    sweep(pcmm.load_scene(path), plan, out, pcmm.RunOptions(t_end=0.5), workers=1)
    (row,) = read_csv(out)
    new_cols = ("first_impulse_magnitude", "peak_impulse_magnitude", "total_impulse_magnitude")
    old_header = [c for c in row if c not in new_cols]
    old_cells = [row[c] for c in old_header[:-1]]
    cut = [c for c in old_cells]
    out.write_text(",".join(old_header) + "\n" + ",".join([*old_cells, checksum(old_cells)]) + "\n")
    res = sweep(pcmm.load_scene(path), make_plan([parse_set("scene.gravity[1]=-9.81,-6.0")]), out,
                pcmm.RunOptions(t_end=0.5), workers=1, resume=True)
    assert res.status == {"complete": 2} and res.ran == 1
    assert res.dropped == ["written before the columns first_impulse_magnitude, peak_impulse_magnitude, "
                           "total_impulse_magnitude: its 1 rows keep them empty (the table is rewritten with them; "
                           "--force runs every row again)"]
    old, new = read_csv(out)
    assert {k: old[k] for k in old_header if k != "check"} == {k: row[k] for k in old_header if k != "check"}
    assert [old[c] for c in new_cols] == ["", "", ""] and old["check"] == checksum(list(old.values())[:-1])
    assert float(new["peak_impulse_magnitude"]) == pytest.approx(housner_impulses(6.0, 1)[0][1], rel=1e-8)
    # resumed again: the table is this study's now, nothing to say
    again = sweep(pcmm.load_scene(path), make_plan([parse_set("scene.gravity[1]=-9.81,-6.0")]), out,
                  pcmm.RunOptions(t_end=0.5), workers=1, resume=True)
    assert again.ran == 0 and again.dropped == []
    # an old row cut short is dropped (and run again), as a current one is
    cut[-1] = cut[-1][:-3]
    out.write_text(",".join(old_header) + "\n" + ",".join([*cut, checksum(old_cells)]) + "\n")
    res = sweep(pcmm.load_scene(path), plan, out, pcmm.RunOptions(t_end=0.5), workers=1, resume=True)
    assert res.ran == 1 and any("cut short or altered" in why for why in res.dropped)
    # any other difference (a swept path, a collected value, a column of its own): refused, naming the columns
    for header in ([h for h in old_header if h != "scene.gravity[1]"], [*old_header[:-1], "stats.steps", "check"]):
        out.write_text(",".join(header) + "\n")
        with pytest.raises(pcmm.errors.UsageError, match="are not this study's"):
            sweep(pcmm.load_scene(path), plan, out, pcmm.RunOptions(t_end=0.5), workers=1, resume=True)


def test_csv_link_position_is_the_frame_origin(walker):
    """docs/cli.md: `x_<link>`, `y_<link>` are the link frame's origin, not its mass centre (the
    compass gait's leg a: the hip; the wheel: the hub, its mass centre too)."""
    name, _, _, _, rows = walker
    link, joint = ("leg_a", "base") if name == "compass_gait" else ("wheel", "hub")
    for r in rows[::25]:
        assert (float(r[f"x_{link} [m]"]), float(r[f"y_{link} [m]"])) == \
            pytest.approx((float(r[f"q_{joint}.x [m]"]), float(r[f"q_{joint}.y [m]"])), abs=1e-14)


def test_walker_strike_momenta_by_hand(walker):
    """Each strike's ``momentum`` record: L and H about the origin recomputed from the recorded
    velocities (point masses, the wheel's I = 0.05), and H about the new foot kept across the strike
    (the only impulse acts there; the trailing foot leaves with none)."""
    name, _, _, traj, _ = walker
    segs = list(traj.segments)
    for e, before, after in zip(traj.events, segs[:-1], segs[1:]):
        mom = e["momentum"]
        assert mom["about"] == [0.0, 0.0]
        for seg, i, key in ((before, -1, "before"), (after, 0, "after")):
            q = dict(zip(seg.coordinates, np.asarray(seg.q[i])))
            v = dict(zip(seg.coordinates, np.asarray(seg.v[i])))
            if name == "rimless_wheel":
                bodies = [(1.0, np.array([q["hub.x"], q["hub.y"]]), np.array([v["hub.x"], v["hub.y"]]))]
                spin = 0.05 * v["hub.theta"]
            else:
                hip, vh = np.array([q["base.x"], q["base.y"]]), np.array([v["base.x"], v["base.y"]])
                ra, rb = rot(q["base.theta"]) @ [0.0, -0.5], rot(q["base.theta"] + q["hip"]) @ [0.0, -0.5]
                bodies = [(10.0, hip, vh), (5.0, hip + ra, vh + v["base.theta"] * cross_k(ra)),
                          (5.0, hip + rb, vh + (v["base.theta"] + v["hip"]) * cross_k(rb))]
                spin = 0.0
            L = sum(m * u for m, _, u in bodies)
            H = spin + sum(m * (p[0] * u[1] - p[1] * u[0]) for m, p, u in bodies)
            assert mom[f"linear_{key}"] == pytest.approx(L.tolist(), abs=1e-12)
            assert mom[f"angular_{key}"] == pytest.approx(H, abs=1e-12)
        (foot,) = e["anchor"].values()
        about_foot = [mom[f"angular_{k}"] - (foot[0] * mom[f"linear_{k}"][1] - foot[1] * mom[f"linear_{k}"][0])
                      for k in ("before", "after")]
        assert about_foot[1] == pytest.approx(about_foot[0], abs=1e-12)
