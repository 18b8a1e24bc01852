"""The differential oracle: every derived series of a run recomputed from its recorded state alone.

A run records, per segment, the configuration's coordinates ``q`` and velocities ``v`` and a
set of series derived from them (link angles and positions, angular velocities, energies,
force elements, constraint forces and holding forces).  This module recomputes each of those
series at sampled instants from ``(t, q, v)`` and the scene's *data* only: its own Pinocchio
model of the URDF (``crba``, ``computePotentialEnergy``, frame placements, frame Jacobians and
classical accelerations), its own force elements, its own constraint rows and its own KKT
solve ``[[M, -J^T], [J, 0]] [a; lam] = [tau - h; -Jdot v]``.  It imports nothing of pcmm's
model, coordinates, constraints, forces, transitions or holding modules: what pcmm computes
and what the oracle computes meet only in the comparison.

Besides the per-sample checks it checks every event (positions continuous, the restitution
law on the contact's normal velocity, momentum conserved in every direction the impulse rows
do not span, kinetic energy not rising where no drive can work, velocities continuous at a
release, the event record's energies against the states on both sides) and
the prefix property (a run to ``t_end`` = T1 < T2 agrees with the run to T2 over [0, T1], its
steps, its ``--dt`` resampling and its CSV alike).

Conventions (the scene's, written down independently): a cut joint's rows are ``p_b - p_a``
(revolute, weld) in world axes, ``n . (p_b - p_a)`` with ``n`` normal to the sliding axis fixed
in a (prismatic), and ``theta_b - theta_a - angle`` (prismatic, weld); a drive's row is
``q_j - f(t)``; a lock's row is ``q_j - value``; a merged stop's row is its contact normal row.
The multipliers satisfy ``M a + h = tau + J^T lam``: a cut joint's forces act on b, a drive's
moment and a latch's holding moment on the joint's child.

Use: ``findings = check_run(scene_path, t_end)`` (a list of :class:`Finding`, empty when every
recomputed number agrees), ``check_prefix(scene_path, t_short, t_long, dt)``.
"""
from __future__ import annotations

import csv
import dataclasses
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
MOVABLE = ("revolute", "continuous", "prismatic", "planar")
TWO_PI = 2 * math.pi


@dataclass
class Finding:
    """One disagreement between a recorded number and its recomputation."""

    scene: str
    t: float
    what: str
    recorded: object
    oracle: object
    error: float

    def __str__(self):
        return (f"{Path(self.scene).name} t = {self.t:.9g} s: {self.what}: recorded {self.recorded!r}, "
                f"oracle {self.oracle!r} (error {self.error:.3g})")


@dataclass
class Tolerances:
    pose: float = 1e-9  # m, rad: a posture recomputed from the same coordinates
    residual: float = 1e-7  # m, rad: a constraint at position level
    residual_rate: float = 1e-6  # m/s, rad/s: at velocity level
    energy: float = 1e-9  # relative to the run's energy scale
    force: float = 1e-6  # relative to the segment's force scale
    event: float = 1e-7  # restitution, momentum, continuity, relative


# ---- the URDF, read by the oracle itself -------------------------------------------------------------
@dataclass
class Joint:
    name: str
    type: str
    parent: str
    child: str
    xyz: tuple
    yaw: float
    axis: tuple


def urdf_text(path) -> str:
    root = ET.parse(path).getroot()
    for parent in root.iter():
        for child in [c for c in parent if c.tag in ("visual", "collision", "material")]:
            parent.remove(child)
    return ET.tostring(root, encoding="unicode")


def urdf_joints(text: str) -> dict[str, Joint]:
    out = {}
    for j in ET.fromstring(text).findall("joint"):
        o = j.find("origin")
        xyz = tuple(float(x) for x in (o.get("xyz", "0 0 0") if o is not None else "0 0 0").split())
        rpy = tuple(float(x) for x in (o.get("rpy", "0 0 0") if o is not None else "0 0 0").split())
        ax = j.find("axis")
        axis = tuple(float(x) for x in (ax.get("xyz", "1 0 0") if ax is not None else "1 0 0").split())
        out[j.get("name")] = Joint(j.get("name"), j.get("type"), j.find("parent").get("link"),
                                   j.find("child").get("link"), xyz, rpy[2], axis)
    return out


class Model:
    """One URDF as a Pinocchio model, its state given by joint name."""

    def __init__(self, text: str, gravity):
        self.text = text
        self.model = pin.buildModelFromXML(text)
        self.model.gravity.linear = np.array([gravity[0], gravity[1], 0.0])
        self.data = self.model.createData()
        self.joints = urdf_joints(text)
        self.movable = {n for n, j in self.joints.items() if j.type in MOVABLE}
        self.nv = self.model.nv
        self.vslice, self.qidx, self.planar = {}, {}, set()
        for jid in range(1, self.model.njoints):
            name, jm = self.model.names[jid], self.model.joints[jid]
            self.vslice[name] = slice(jm.idx_v, jm.idx_v + jm.nv)
            self.qidx[name] = jm.idx_q
            if jm.nv == 3:
                self.planar.add(name)

    def frame(self, link: str) -> int:
        return self.model.getFrameId(link, pin.FrameType.BODY)

    def state(self, values: dict[str, np.ndarray], rates: dict[str, np.ndarray]):
        """Pinocchio's (q, v) from {joint: values} (a planar joint's x, y, theta) and rates."""
        q, v = pin.neutral(self.model), np.zeros(self.nv)
        for name, sl in self.vslice.items():
            x = np.atleast_1d(values[name]).astype(float)
            i = self.qidx[name]
            r = np.atleast_1d(rates.get(name, np.zeros(sl.stop - sl.start))).astype(float)
            if name in self.planar:
                c, s = math.cos(x[2]), math.sin(x[2])
                q[i:i + 4] = [x[0], x[1], c, s]
                # recorded x', y' are world-axes rates; Pinocchio's planar v is in the body's axes
                r = np.array([c * r[0] + s * r[1], -s * r[0] + c * r[1], r[2]])
            else:
                q[i] = x[0]
            v[sl] = r
        return q, v

    def kinematics(self, q, v):
        a0 = np.zeros(self.nv)
        pin.forwardKinematics(self.model, self.data, q, v, a0)
        pin.computeJointJacobians(self.model, self.data, q)
        pin.updateFramePlacements(self.model, self.data)

    def pose(self, link: str):
        M = self.data.oMf[self.frame(link)]
        return M.translation[:2].copy(), math.atan2(M.rotation[1, 0], M.rotation[0, 0])

    def jacobian(self, link: str, local=(0.0, 0.0)):
        """(point, J (3 x nv): rows vx, vy, omega) of a point fixed on ``link``."""
        fid = self.frame(link)
        M = self.data.oMf[fid]
        J = np.asarray(pin.getFrameJacobian(self.model, self.data, fid, LWA)).reshape(6, self.nv)
        r = M.rotation[:2, :2] @ np.asarray(local, float)
        Jp = J[:2] + np.outer([-r[1], r[0]], J[5])
        return M.translation[:2] + r, np.vstack([Jp, J[5]])

    def acceleration_bias(self, link: str, local=(0.0, 0.0)):
        """(point acceleration at a = 0 (Jdot v), omega) of a point on ``link``."""
        fid = self.frame(link)
        acc = pin.getFrameClassicalAcceleration(self.model, self.data, fid, LWA).linear[:2]
        w = pin.getFrameVelocity(self.model, self.data, fid, LWA).angular[2]
        r = self.data.oMf[fid].rotation[:2, :2] @ np.asarray(local, float)
        return acc - w * w * r, w  # the origin's acceleration plus the centripetal one of the arm


# ---- one recorded segment seen by the oracle ------------------------------------------------------------
def _coordinate_values(seg, i) -> tuple[dict, dict]:
    values, rates = {}, {}
    for k, name in enumerate(seg.coordinates):
        joint, _, part = name.partition(".")
        if part:
            values.setdefault(joint, []).append(seg.q[i, k])
            rates.setdefault(joint, []).append(seg.v[i, k])
        else:
            values[joint], rates[joint] = seg.q[i, k], seg.v[i, k]
    return values, rates


def _poly(coefficients, t, order=0):
    c = np.polynomial.polynomial.Polynomial(coefficients)
    for _ in range(order):
        c = c.deriv()
    return float(c(t))


def _kind(what: str) -> str:
    """The kind of a comparison, without the configuration, joint or link it names."""
    for kind in ("without impulse", "impulse P", "v_after", "constraint force",
                 "kinetic energy rises beyond the drives' work", "kinetic energy rises", "momentum not conserved", "normal velocity after", "kinetic_energy_after", "kinetic_energy_before",
                 "without impact", "residual rate", "residual", "force element", "potential energy",
                 "kinetic energy", "omega of", "theta of", "x,y of", "jumps", "segments meet"):
        if kind in what:
            return kind
    return what


class Oracle:
    """The oracle of one scene: its configurations as URDF models, locks and holds by name."""

    def __init__(self, scene, tol: Tolerances | None = None):
        self.scene = scene
        self.tol = tol or Tolerances()
        self.findings: list[Finding] = []
        self._models: dict[str, Model] = {}
        # configuration -> its URDF's text (a derived configuration's: its root URDF, its locks as rows)
        self.texts = {name: urdf_text(spec.urdf) for name, spec in scene.configurations.items()}
        self.counts: dict[str, int] = {}  # how many comparisons of each kind were made

    def model(self, text: str) -> Model:
        if text not in self._models:
            self._models[text] = Model(text, self.scene.gravity)
        return self._models[text]

    def report(self, t, what, recorded, oracle, error, tol):
        self.counts[_kind(what)] = self.counts.get(_kind(what), 0) + 1
        if not (error <= tol):
            self.findings.append(Finding(str(self.scene.path), float(t), what, recorded, oracle, float(error)))

    # -- which joints a segment holds, and the model it is solved in
    def hold_joints(self, label: str, free_in_source=None) -> set[str]:
        joint = label[:-len(".hold")]
        tr = next((t for t in self.scene.transitions if t.name == joint), None)
        if tr is not None and getattr(tr, "merge_to", None):  # a merged stop: the joints its merge locks
            return self._free(tr.source) - self._free(tr.merge_to)
        return {joint}

    def _free(self, config: str) -> set[str]:
        spec = self.scene.configurations[config]
        movable = self.model(self.texts[config]).movable
        return movable - set(spec.derivation.lock) if spec.derivation is not None else movable

    def free_model(self, config: str, need: set[str]) -> Model:
        """The scene URDF with every joint of ``need`` free, fewest joints first."""
        fits = sorted((len(self.model(txt).movable), name) for name, txt in self.texts.items()
                      if need <= self.model(txt).movable)
        if not fits:
            raise AssertionError(f"oracle: no URDF of the scene has {sorted(need)} free")
        own = self.model(self.texts[config])
        return own if need <= own.movable else self.model(self.texts[fits[0][1]])

    # -- the whole run
    def check(self, traj, samples: int = 6, locks: dict | None = None):
        """Check every segment at ``samples`` instants, and every switch; ``locks`` gives the values of
        joints locked where the trajectory starts, if it starts in a derived configuration entered
        before (a part of a run)."""
        self.start_locks = dict(locks or {})
        locks: dict[str, float] = {}  # joint -> value while locked (from the last state it was free)
        prev = None
        contexts = []
        for k, seg in enumerate(traj.segments):
            ctx = self.segment_context(seg, prev, locks)
            contexts.append(ctx)
            n = len(seg.t)
            idx = sorted(set(np.linspace(0, n - 1, min(samples, n)).round().astype(int).tolist()))
            for i in idx:
                self.check_sample(seg, ctx, i)
            prev = (seg, ctx)
        self.check_events(traj, contexts)
        return self.findings

    def segment_context(self, seg, prev, locks):
        spec = self.scene.configurations[seg.configuration]
        free = {c.partition(".")[0] for c in seg.coordinates}
        held = {lab: self.hold_joints(lab) for lab in seg.constraint_labels if lab.endswith(".hold")}
        need = free.union(*held.values()) if held else set(free)
        F = self.free_model(seg.configuration, need)
        own = self.model(self.texts[seg.configuration])
        locked = sorted(F.movable - free)
        values = {}
        known = dict(spec.derivation.values) if spec.derivation is not None else {}
        for j in locked:
            if j in known:
                values[j] = known[j]
            elif prev is not None and j in {c.partition(".")[0] for c in prev[0].coordinates}:
                pseg = prev[0]
                values[j] = float(pseg.q[-1, pseg.coordinates.index(j)])
            elif prev is not None and j in prev[1]["locks"]:
                values[j] = prev[1]["locks"][j]
            elif prev is None and j in getattr(self, "start_locks", {}):
                values[j] = self.start_locks[j]
            else:
                values[j] = None
        if any(v is None for v in values.values()) or (spec.derivation is None and own is not F):
            # the configuration's own URDF fixes them: read their values off its link poses
            fv, fr = _coordinate_values(seg, 0)
            q0, v0 = own.state(fv, fr)
            own.kinematics(q0, v0)
            for j in locked:
                joint = F.joints[j]
                (pp, tp), (pc, tc) = own.pose(joint.parent), own.pose(joint.child)
                if joint.type in ("revolute", "continuous"):
                    x = tc - tp - joint.yaw
                    ref = values[j] if values[j] is not None else 0.0
                    x += TWO_PI * round((ref - x) / TWO_PI)
                else:
                    c, s = math.cos(tp), math.sin(tp)
                    rel = np.array([[c, s], [-s, c]]) @ (pc - pp) - np.asarray(joint.xyz[:2])
                    cy, sy = math.cos(joint.yaw), math.sin(joint.yaw)
                    along = np.array([[cy, sy], [-sy, cy]]) @ rel
                    a = np.asarray(joint.axis[:2]) / np.linalg.norm(joint.axis[:2])
                    x = float(a @ along)
                values[j] = x
        # the force elements acting: the configuration's own, plus a held joint's own elements as the
        # configuration with that joint free has them (the lock carries them)
        forces = list(self.scene.forces_in(seg.configuration))
        for joints in held.values():
            for name in self.scene.configurations:
                if not joints <= self._free(name):
                    continue
                for f in self.scene.forces_in(name):
                    touches = ((f.on is not None and f.on.kind == "joint" and f.on.name in joints)
                               or (f.measure is not None and f.measure.kind == "joint" and f.measure.names[0] in joints))
                    if touches and f not in forces:
                        forces.append(f)
        return {"model": F, "locks": values, "held": held, "forces": forces, "spec": spec,
                "drives": self.scene.drives_in(seg.configuration)}

    # -- one sample
    def state(self, seg, ctx, i):
        F = ctx["model"]
        values, rates = _coordinate_values(seg, i)
        values.update(ctx["locks"])
        q, v = F.state(values, rates)
        F.kinematics(q, v)
        return F, q, v

    def angles(self, seg, ctx, i, F):
        """Each link's absolute angle on the recorded series' 2 pi branch."""
        out = {}
        for k, link in enumerate(seg.links):
            th = F.pose(link)[1]
            out[link] = th + TWO_PI * round((seg.theta[i, k] - th) / TWO_PI)
        return out

    def measure(self, m, F, q, v, theta, seg):
        """(value, rate) of a force element's or guard's measure."""
        if m.kind == "joint":
            sl = F.vslice[m.names[0]]
            return float(q[F.qidx[m.names[0]]]), float(v[sl.start])
        w = {name: F.jacobian(name)[1][2] @ v for name in m.names}
        if m.kind == "link":
            return theta[m.names[0]], w[m.names[0]]
        a, b = m.names
        return theta[b] - theta[a], w[b] - w[a]

    def generalized_forces(self, ctx, F, q, v, theta, seg):
        """({element: value}, tau) of the acting force elements."""
        values, tau = {}, np.zeros(F.nv)
        for f in ctx["forces"]:
            if f.points is not None:
                pa, Ja = F.jacobian(f.points.a, f.points.point_a)
                pb, Jb = F.jacobian(f.points.b, f.points.point_b)
                r = pb - pa
                L = float(np.hypot(*r))
                u = r / L
                uJ = u @ (Jb[:2] - Ja[:2])
                val = f.value - f.k * (L - f.rest) - f.c * float(uJ @ v)
                values[f.name], tau = val, tau + val * uJ
                continue
            x, xd = self.measure(f.measure, F, q, v, theta, seg) if f.measure is not None else (0.0, 0.0)
            val = f.value - f.k * (x - f.rest) - f.c * xd
            if f.on.kind == "joint":
                col = np.zeros(F.nv)
                col[F.vslice[f.on.name].start] = 1.0
            else:
                col = F.jacobian(f.on.name)[1][2]
            values[f.name], tau = val, tau + val * col
        return values, tau

    def potential(self, ctx, F, q, v, theta, seg):
        pe = pin.computePotentialEnergy(F.model, F.data, q)
        for f in ctx["forces"]:  # the configuration's own and a held joint's (at its locked value: constant)
            if f.points is not None:
                pa, pb = F.jacobian(f.points.a, f.points.point_a)[0], F.jacobian(f.points.b, f.points.point_b)[0]
                pe += 0.5 * f.k * (float(np.hypot(*(pb - pa))) - f.rest) ** 2
            elif f.measure is not None:
                pe += 0.5 * f.k * (self.measure(f.measure, F, q, v, theta, seg)[0] - f.rest) ** 2
        return pe

    def cut_rows(self, cj, F, q, v):
        """(residual, J, bias) of one cut joint: rows named as pcmm labels them."""
        pa, Ja = F.jacobian(cj.a, cj.point_a)
        pb, Jb = F.jacobian(cj.b, cj.point_b)
        acc_a, wa = F.acceleration_bias(cj.a, cj.point_a)
        acc_b, _ = F.acceleration_bias(cj.b, cj.point_b)
        ta, tb = F.pose(cj.a)[1], F.pose(cj.b)[1]
        rel = tb - ta
        phi, rows, bias = [], [], []
        if cj.type in ("revolute", "weld"):
            phi += list(pb - pa)
            rows += [Jb[0] - Ja[0], Jb[1] - Ja[1]]
            bias += list(acc_b - acc_a)
        if cj.type == "prismatic":
            axis = np.asarray(cj.axis, float) / np.linalg.norm(cj.axis)
            c, s = math.cos(ta), math.sin(ta)
            n = np.array([[c, -s], [s, c]]) @ np.array([-axis[1], axis[0]])
            nperp = np.array([-n[1], n[0]])  # n' = w_a nperp
            r, rdot = pb - pa, (Jb[:2] - Ja[:2]) @ v
            phi.append(float(n @ r))
            rows.append(n @ (Jb[:2] - Ja[:2]) + (nperp @ r) * Ja[2])
            bias.append(float(-wa * wa * (n @ r) + 2 * wa * (nperp @ rdot) + n @ (acc_b - acc_a)))
        if cj.type in ("prismatic", "weld"):
            d = rel - cj.angle
            phi.append(math.atan2(math.sin(d), math.cos(d)))
            rows.append(Jb[2] - Ja[2])
            bias.append(0.0)
        return np.array(phi), np.array(rows).reshape(len(phi), F.nv), np.array(bias)

    def contact_row(self, contact, F, q, v):
        """(J_n, bias) of a contact's normal row (from a to b, n fixed in a; a joint stop: -s e_j)."""
        if contact.joint is not None:
            row = np.zeros(F.nv)
            row[F.vslice[contact.joint].start] = -contact.stop_sign
            return row, 0.0
        _, Ja = F.jacobian(contact.a, contact.point_a)
        _, Jb = F.jacobian(contact.b, contact.point_b)
        acc_a, wa = F.acceleration_bias(contact.a, contact.point_a)
        acc_b, _ = F.acceleration_bias(contact.b, contact.point_b)
        ta = F.pose(contact.a)[1]
        c, s = math.cos(ta), math.sin(ta)
        n = np.array([[c, -s], [s, c]]) @ np.asarray(contact.normal, float)
        n /= np.linalg.norm(n)
        vrel = (Jb[:2] - Ja[:2]) @ v
        return n @ (Jb[:2] - Ja[:2]), float(n @ (acc_b - acc_a) + wa * np.array([-n[1], n[0]]) @ vrel)

    def anchored(self, seg, ctx, i):
        """The configuration's cut joints, a joint anchored at entry (``point_a = "entry"``, a struck
        point pinned where it lands) given the world point where b's point was at the segment's
        first sample; the later samples then check that the point stays there. Leaves the model
        at sample ``i``'s state."""
        joints = list(ctx["spec"].cut_joints)
        if any(getattr(cj, "anchor_at_entry", False) for cj in joints):
            F0 = self.state(seg, ctx, 0)[0]
            joints = [dataclasses.replace(cj, point_a=tuple(float(x) for x in F0.jacobian(cj.b, cj.point_b)[0]))
                      if getattr(cj, "anchor_at_entry", False) else cj for cj in joints]
            self.state(seg, ctx, i)
        return joints

    def check_sample(self, seg, ctx, i):
        F, q, v = self.state(seg, ctx, i)
        t, tol = float(seg.t[i]), self.tol
        theta = self.angles(seg, ctx, i, F)
        for k, link in enumerate(seg.links):
            xy, th = F.pose(link)
            self.report(t, f"{seg.configuration}: x,y of {link}", seg.xy[i, k].tolist(), xy.tolist(),
                        float(np.max(np.abs(seg.xy[i, k] - xy))), tol.pose)
            d = (seg.theta[i, k] - th + math.pi) % TWO_PI - math.pi
            self.report(t, f"{seg.configuration}: theta of {link}", seg.theta[i, k], th, abs(d), tol.pose)
            w = float(F.jacobian(link)[1][2] @ v)
            self.report(t, f"{seg.configuration}: omega of {link}", seg.omega[i, k], w,
                        abs(seg.omega[i, k] - w), tol.pose * max(1.0, abs(w)))
        M = pin.crba(F.model, F.data, q)
        M = np.triu(M) + np.triu(M, 1).T
        ke = 0.5 * v @ M @ v
        scale = max(1.0, abs(ke), abs(seg.potential[i]))
        self.report(t, f"{seg.configuration}: kinetic energy", seg.kinetic[i], ke, abs(seg.kinetic[i] - ke),
                    tol.energy * scale)
        pe = self.potential(ctx, F, q, v, theta, seg)
        self.report(t, f"{seg.configuration}: potential energy", seg.potential[i], pe,
                    abs(seg.potential[i] - pe), tol.energy * scale)
        values, tau = self.generalized_forces(ctx, F, q, v, theta, seg)
        for k, name in enumerate(seg.force_names):
            self.report(t, f"{seg.configuration}: force element {name}", seg.forces[i, k], values.get(name),
                        abs(seg.forces[i, k] - values.get(name, math.nan)),
                        tol.force * max(1.0, abs(values.get(name, 0.0))))
        # the configuration's constraints at position and velocity level, then the KKT solve
        rows, bias, labels = [], [], []
        for cj in self.anchored(seg, ctx, i):
            phi, J, b = self.cut_rows(cj, F, q, v)
            names = {"revolute": ["fx", "fy"], "prismatic": ["fn", "mz"], "weld": ["fx", "fy", "mz"]}[cj.type]
            for r in range(len(phi)):
                self.report(t, f"{seg.configuration}: cut joint {cj.name} residual {names[r]}", 0.0, phi[r],
                            abs(phi[r]), tol.residual)
                self.report(t, f"{seg.configuration}: cut joint {cj.name} residual rate {names[r]}", 0.0,
                            float(J[r] @ v), abs(J[r] @ v), tol.residual_rate)
            rows += list(J)
            bias += list(b)
            labels += [f"{cj.name}.{n}" for n in names]
        for d in ctx["drives"]:
            sl = F.vslice[d.joint]
            e = np.zeros(F.nv)
            e[sl.start] = 1.0
            x, xd = float(q[F.qidx[d.joint]]), float(v[sl.start])
            self.report(t, f"{seg.configuration}: drive {d.joint} residual", _poly(d.coefficients, t), x,
                        abs(x - _poly(d.coefficients, t)), tol.residual)
            self.report(t, f"{seg.configuration}: drive {d.joint} residual rate", _poly(d.coefficients, t, 1), xd,
                        abs(xd - _poly(d.coefficients, t, 1)), tol.residual_rate)
            rows.append(e)
            bias.append(-_poly(d.coefficients, t, 2))
            labels.append(f"{d.joint}.drive")
        held_joints = {j: lab for lab, js in ctx["held"].items() for j in js}
        merged = set()
        for j in ctx["locks"]:
            lab = held_joints.get(j)
            tr = next((x for x in self.scene.transitions if lab is not None and x.name == lab[:-5]), None)
            if tr is not None and getattr(tr, "merge_to", None) and tr.contact is not None:
                if lab in merged:
                    continue
                Jn, bn = self.contact_row(tr.contact, F, q, v)
                if len(ctx["held"][lab]) == 1:  # one joint merged: the contact's normal row holds it
                    rows.append(Jn)
                    bias.append(bn)
                    labels.append(lab)
                    merged.add(lab)
                    continue
            e = np.zeros(F.nv)
            e[F.vslice[j].start] = 1.0
            rows.append(e)
            bias.append(0.0)
            labels.append(lab if lab is not None and lab not in merged else f"{j}.lock")
        if not rows or not seg.constraint_labels:
            return
        J, b = np.array(rows), np.array(bias)
        h = pin.nonLinearEffects(F.model, F.data, q, v)
        K = np.block([[M, -J.T], [J, np.zeros((len(J), len(J)))]])
        sol = np.linalg.lstsq(K, np.concatenate([tau - h, -b]), rcond=None)[0]
        lam = dict(zip(labels, sol[F.nv:]))
        scale = max(1.0, float(np.max(np.abs(seg.constraint_forces[i]), initial=0.0)))
        for k, lab in enumerate(seg.constraint_labels):
            if lab in lam:
                self.report(t, f"{seg.configuration}: constraint force {lab}", seg.constraint_forces[i, k],
                            float(lam[lab]), abs(seg.constraint_forces[i, k] - lam[lab]), tol.force * scale)
            else:
                self.report(t, f"{seg.configuration}: constraint force {lab} has no row in the oracle",
                            seg.constraint_forces[i, k], None, math.inf, 0.0)

    # -- events
    def check_events(self, traj, contexts):
        segs = traj.segments
        # each switch between consecutive segments, with the events at that instant: where several
        # switches share one instant (simultaneous contacts), one event each, in order
        def when(e):
            return e.get("t_end", e["t"])
        events = [e for e in traj.events if "t" in e]
        bounds = [float(segs[k + 1].t[0]) for k in range(len(segs) - 1)]
        used = 0
        for k, t in enumerate(bounds):
            a, b = segs[k], segs[k + 1]
            self.report(t, "segments meet in time", float(a.t[-1]), t, abs(float(a.t[-1]) - t), 1e-12 * max(1, t))
            while used < len(events) and when(events[used]) < t - 1e-12 * max(1.0, t):
                used += 1
            at_t = [e for e in events[used:] if abs(when(e) - t) <= 1e-12 * max(1.0, t)]
            left = sum(1 for u in bounds[k:] if u == t)
            here = at_t[:1] if len(at_t) == left else (at_t if left == 1 else [])
            used += len(here)
            self.check_switch(a, contexts[k], b, contexts[k + 1], here)

    def check_switch(self, a, ca, b, cb, here):
        t, tol = float(b.t[0]), self.tol
        Fa, qa, va = self.state(a, ca, len(a.t) - 1)
        links = [l for l in b.links if l in a.links]
        pos_a = {l: Fa.pose(l) for l in links}
        ja = {l: Fa.jacobian(l)[1] for l in links}
        M = pin.crba(Fa.model, Fa.data, qa)
        M = np.triu(M) + np.triu(M, 1).T
        ke_a = 0.5 * va @ M @ va
        Fb, qb, vb = self.state(b, cb, 0)
        Mb = pin.crba(Fb.model, Fb.data, qb)
        ke_b = 0.5 * vb @ (np.triu(Mb) + np.triu(Mb, 1).T) @ vb
        Fb.kinematics(qb, vb)
        for l in links:  # positions never jump
            (xa, tha), (xb, thb) = pos_a[l], Fb.pose(l)
            self.report(t, f"{a.configuration} -> {b.configuration}: position of {l} jumps", xa.tolist(), xb.tolist(),
                        float(np.max(np.abs(xa - xb))), tol.event)
            d = (tha - thb + math.pi) % TWO_PI - math.pi
            self.report(t, f"{a.configuration} -> {b.configuration}: angle of {l} jumps", tha, thb, abs(d), tol.event)
            ia, ib = a.links.index(l), b.links.index(l)
            self.report(t, f"{a.configuration} -> {b.configuration}: recorded theta of {l} jumps",
                        a.theta[-1, ia], b.theta[0, ib], abs(a.theta[-1, ia] - b.theta[0, ib]), 1e-6)
        impact = any(e.get("impact") for e in here)
        scale = max(ke_a, ke_b, 1e-9)
        for e in here:
            if "kinetic_energy_after" in e and e is here[-1]:
                self.report(t, f"event '{e['name']}': kinetic_energy_after vs the next segment's first state",
                            e["kinetic_energy_after"], ke_b, abs(e["kinetic_energy_after"] - ke_b), tol.event * max(1, scale))
            if isinstance(e.get("v_after"), dict) and e is here[-1]:  # the velocity the run goes on with
                values, rates = _coordinate_values(b, 0)
                for j, x in e["v_after"].items():
                    if j in rates and np.atleast_1d(rates[j]).size == 3:
                        # the event record keeps a planar joint's velocity in body axes, the series in
                        # world axes (docs/planar_joints.md): compare in body axes
                        c, s_ = math.cos(values[j][2]), math.sin(values[j][2])
                        w = np.atleast_1d(rates[j])
                        rates = {**rates, j: [c * w[0] + s_ * w[1], -s_ * w[0] + c * w[1], w[2]]}
                    if j in rates:
                        d = float(np.max(np.abs(np.atleast_1d(rates[j]) - np.atleast_1d(x))))
                        self.report(t, f"event '{e['name']}': v_after of {j} vs the next segment's first state",
                                    x, rates[j], d, tol.event * max(1.0, float(np.max(np.abs(np.atleast_1d(x))))))
            if "kinetic_energy_before" in e and e is here[0] and "duration" not in e:
                self.report(t, f"event '{e['name']}': kinetic_energy_before vs the last state before it",
                            e["kinetic_energy_before"], ke_a, abs(e["kinetic_energy_before"] - ke_a), tol.event * max(1, scale))
        if any("duration" in e for e in here):
            # a collision resolved by a continuous contact law ends here: its energy after is checked
            # above; over its duration the forces and gravity act, so no impulse balance applies
            return
        drives = bool(ca["drives"]) or bool(cb["drives"])
        if not drives:
            self.report(t, f"{a.configuration} -> {b.configuration}: kinetic energy rises at the switch", ke_a, ke_b,
                        ke_b - ke_a, tol.event * scale)
        dropped = {j: x for e in here for j, x in (e.get("dropped_velocities") or {}).items()}
        changed = {j: x for e in here for j, x in (e.get("changed_velocities") or {}).items()}
        if not impact and dropped:  # a switch without impulse (impact = False): the velocities it drops are named
            _, ra = _coordinate_values(a, len(a.t) - 1)
            _, rb = _coordinate_values(b, 0)
            for j, x in ra.items():
                what = f"{a.configuration} -> {b.configuration} without impulse: velocity of {j}"
                if j in changed and j in rb:  # changed to fit the target's constraints: named, before and after
                    for k, (told, real) in enumerate(((changed[j][0], x), (changed[j][1], rb[j]))):
                        d = float(np.max(np.abs(np.atleast_1d(told) - np.atleast_1d(real))))
                        self.report(t, what + (" before", " after")[k] + " (the event's changed_velocities)", told,
                                    real, d, tol.event * max(1.0, float(np.max(np.abs(np.atleast_1d(real))))))
                if j in dropped:
                    d = float(np.max(np.abs(np.atleast_1d(dropped[j]) - np.atleast_1d(x))))
                    self.report(t, what + " dropped (the event's dropped_velocities)", dropped[j], x, d,
                                tol.event * max(1.0, float(np.max(np.abs(np.atleast_1d(x))))))
                elif j in changed and j in rb:
                    pass  # named with both rates above
                elif j in rb:
                    d = float(np.max(np.abs(np.atleast_1d(rb[j]) - np.atleast_1d(x))))
                    self.report(t, what + " kept", x, rb[j], d,
                                tol.event * max(1.0, float(np.max(np.abs(np.atleast_1d(x))))))
                else:
                    self.report(t, what + " dropped but not named in the event's dropped_velocities", 0.0, x,
                                math.inf, 0.0)
            return
        if not impact:  # a release, an unmerge, a repartition: velocities continuous
            for l in links:
                wa, wb = ja[l][2] @ va, Fb.jacobian(l)[1][2] @ vb
                self.report(t, f"{a.configuration} -> {b.configuration} without impact: omega of {l} jumps",
                            float(wa), float(wb), abs(wa - wb), tol.event * max(1.0, abs(wa)))
            return
        # momentum: M (v+ - v-) lies in the span of the impulse's rows (contact normals, the joints the
        # switch locks, the loops' and drives' rows), all in the source's coordinates at the same posture
        Fa.kinematics(qa, va)
        vplus = np.zeros(Fa.nv)
        _, brates = _coordinate_values(b, 0)
        for name, sl in Fa.vslice.items():
            if name in brates:  # Pinocchio's v of the target's first state (a planar joint's in body axes)
                vplus[sl] = vb[Fb.vslice[name]] if name in Fb.vslice else np.atleast_1d(brates[name])
        # velocities the target does not have as coordinates: zero (locked)
        rows = []
        contact_events = 0
        together = []  # (event, contact's name, its row index): contacts closed at once, one impulse
        for e in here:
            if "simultaneous" in e:
                for name, c in e["simultaneous"].items():
                    tr = next(x for x in self.scene.transitions if x.name == name)
                    together.append((e, name, len(rows)))
                    rows.append(self.contact_row(tr.contact, Fa, qa, va)[0])
                    vn_m, vn_p = float(rows[-1] @ va), float(rows[-1] @ vplus)
                    target = -c["restitution"] * min(vn_m, 0.0)
                    self.report(t, f"event '{e['name']}': {name}'s normal velocity after ({c['mode']})",
                                c["normal_velocity"]["after"], vn_p, abs(c["normal_velocity"]["after"] - vn_p),
                                tol.event * max(1.0, abs(vn_m)))
                    if c["mode"] != "separate":  # held: Newton's law on its normal
                        self.report(t, f"event '{e['name']}': {name} held with restitution {c['restitution']}",
                                    vn_p, target, abs(vn_p - target), tol.event * max(1.0, abs(vn_m)))
                    if tr.contact.friction is not None:  # its tangential row (t = (n_y, -n_x), in a's frame)
                        nrm = tr.contact.normal
                        tang = dataclasses.replace(tr.contact, normal=(nrm[1], -nrm[0]))
                        rows.append(self.contact_row(tang, Fa, qa, va)[0])
                continue
            tr = next((x for x in self.scene.transitions if x.name == e["name"]), None)
            if tr is None or tr.contact is None:
                continue
            Jn, _ = self.contact_row(tr.contact, Fa, qa, va)
            rows.append(Jn)
            contact_events += 1
            vn_m, vn_p = float(Jn @ va), float(Jn @ vplus)
            restitution = e.get("restitution", 0.0) if e["to"] == e["from"] else 0.0
            if e.get("law", "impulse") == "impulse" and e is here[-1] and len(here) == 1:
                self.report(t, f"event '{e['name']}': normal velocity after (restitution {restitution})",
                            e["normal_velocity"]["after"], -restitution * vn_m, abs(vn_p + restitution * vn_m),
                            tol.event * max(1.0, abs(vn_m)))
        for cj in list(ca["spec"].cut_joints) + [c for c in cb["spec"].cut_joints if c not in ca["spec"].cut_joints]:
            rows += list(self.cut_rows(cj, Fa, qa, va)[1])
        driven = {d.joint for d in list(ca["drives"]) + list(cb["drives"])}
        drive_rows = []  # (row index, coordinate) of the drives' rows
        for name, sl in Fa.vslice.items():
            if name not in brates or name in driven:
                for c in range(sl.start, sl.stop):
                    e_ = np.zeros(Fa.nv)
                    e_[c] = 1.0
                    if name in driven:
                        drive_rows.append((len(rows), c))
                    rows.append(e_)
        r = M @ (vplus - va)
        impulses = None
        if rows:
            R = np.array(rows).T
            impulses = np.linalg.lstsq(R, r, rcond=None)[0]
            r = r - R @ impulses
            if np.linalg.matrix_rank(R) < R.shape[1]:
                impulses = None  # redundant rows: the impulses, and a drive's share, are not unique
        p = float(np.linalg.norm(M @ va))
        self.report(t, f"{a.configuration} -> {b.configuration}: momentum not conserved outside the impulse's rows",
                    0.0, float(np.linalg.norm(r)), float(np.linalg.norm(r)), tol.event * max(1.0, p))
        if impulses is not None and contact_events == 1 and len(here) == 1:
            # the contact's impulse is the first row's, unique where the rows are independent (Eqs. 21-43)
            imp = here[0].get("impulse") or {}
            P = imp.get("moment", imp.get("normal"))
            if P is not None:
                self.report(t, f"event '{here[0]['name']}': impulse P", P, float(impulses[0]),
                            abs(P - impulses[0]), tol.event * max(1.0, abs(impulses[0]), p))
        if impulses is not None:
            for e, name, i in together:  # each contact's normal impulse, unique where the rows are independent
                P = e["simultaneous"][name]["impulse"]["normal"]
                self.report(t, f"event '{e['name']}': {name}'s normal impulse", P, float(impulses[i]),
                            abs(P - impulses[i]), tol.event * max(1.0, abs(impulses[i]), p))
        if drives and impulses is not None:
            # the drive's impulse P works P f'(t) (its coordinate's rate is prescribed, the same on both
            # sides); every other row's impulse works P (v- + v+) / 2 <= 0 (restitution <= 1, locks)
            work = sum(float(impulses[i] * va[c]) for i, c in drive_rows)
            self.report(t, f"{a.configuration} -> {b.configuration}: kinetic energy rises beyond the drives' work "
                        f"({work:.6g} J)", ke_a + work, ke_b, ke_b - ke_a - work, tol.event * max(scale, abs(work)))


# ---- runs --------------------------------------------------------------------------------------------------
def run(scene_path, t_end=None, **options):
    import pcmm
    scene = pcmm.load_scene(scene_path)
    opts = pcmm.RunOptions(t_end=t_end, **options) if t_end is not None else pcmm.RunOptions(**options)
    return scene, pcmm.simulate(scene, opts)


def check_run(scene_path, t_end=None, samples: int = 6, tol: Tolerances | None = None, traj=None, **options):
    """Findings of the oracle on the run of ``scene_path`` to ``t_end`` (and on its trajectory
    resampled at ``dt`` if given as ``options['dt']``)."""
    dt = options.pop("dt", None)
    scene, traj0 = run(scene_path, t_end, **options) if traj is None else (__import__("pcmm").load_scene(scene_path), traj)
    oracle = Oracle(scene, tol)
    oracle.check(traj0, samples)
    if dt is not None:
        oracle.check(traj0.resampled(dt), samples)
    return oracle.findings


def _csv_rows(path) -> tuple[list[str], dict[float, list[str]]]:
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    out = {}
    for r in rows[1:]:
        out.setdefault(float(r[0]), []).append(r)
    return rows[0], out


def compare_csv(short, long, rel: float = 1e-7) -> list[str]:
    """Every row of the CSV ``short`` whose time the CSV ``long`` has must agree with it, column by
    column name (the longer run may have more columns: a lock it reaches later)."""
    problems = []
    hs, rs = _csv_rows(short)
    hl, rl = _csv_rows(long)
    missing = [h for h in hs if h not in hl]
    if missing:
        problems.append(f"CSV columns of the shorter run missing in the longer one: {missing}")
    col = {h: hl.index(h) for h in hs if h in hl}
    for tt, rows in rs.items():
        for ra, rb in zip(rows, rl.get(tt, [])):
            for c, h in enumerate(hs):
                x, y = ra[c], rb[col[h]] if h in col else None
                if y is None or x == y:
                    continue
                try:
                    fx, fy = float(x), float(y)
                except ValueError:
                    problems.append(f"CSV t = {tt}: {h}: {x!r} vs {y!r}")
                    continue
                if not abs(fx - fy) <= rel * max(1.0, abs(fy)) * 10:
                    problems.append(f"CSV t = {tt}: {h}: {x} vs {y}")
    return problems


_SERIES = ("q", "v", "theta", "omega", "xy", "kinetic", "potential", "forces", "constraint_forces")


def _differ(where: str, times, pairs, rel: float, note: str = "") -> list[str]:
    """One message per series ``(A, B, name)`` of ``pairs`` whose largest difference exceeds
    ``rel`` times its scale (max |B|, at least 1), naming the time of the largest."""
    out = []
    for A, B, name in pairs:
        scale = max(1.0, float(np.max(np.abs(B), initial=0.0)))
        err = float(np.max(np.abs(A - B), initial=0.0))
        if not err <= rel * scale:
            j = int(np.argmax(np.max(np.abs(A - B).reshape(len(times), -1), axis=1)))
            out.append(f"{where} {name} differs by {err:.3g} at t = {times[j]:.9g} s (scale {scale:.3g}){note}")
    return out


def check_prefix(scene_path, t_short: float, t_long: float, dt: float, folder: Path, rel: float = 1e-7,
                 rel_dense: float = 1e-6, **options) -> list[str]:
    """The run to ``t_short`` must be the first part of the run to ``t_long``: same events,
    the same series at every common sample time (``rel``), the same ``dt`` resampling and CSV rows;
    where the sample times differ (the integrators' steps depend on the distance to t_end), the
    shorter run's samples agree with the longer run's dense output at their times (``rel_dense``)."""
    _, short = run(scene_path, t_short, **options)
    _, long = run(scene_path, t_long, **options)
    problems = []
    ev_s = [(e["name"], e["t"]) for e in short.events]
    ev_l = [(e["name"], e["t"]) for e in long.events if e["t"] <= float(short.t[-1])]
    if [n for n, _ in ev_s] != [n for n, _ in ev_l[:len(ev_s)]] or any(
            abs(a - b) > 1e-9 for (_, a), (_, b) in zip(ev_s, ev_l)):
        problems.append(f"events differ: {ev_s[:5]} vs {ev_l[:5]}")
    for kind, (ts, tl) in {"steps": (short, long), "dt": (short.resampled(dt), long.resampled(dt))}.items():
        for k, s in enumerate(ts.segments):
            if k >= len(tl.segments):
                problems.append(f"{kind}: segment {k} missing in the longer run")
                break
            l = tl.segments[k]
            common, i_s, i_l = np.intersect1d(s.t, l.t, return_indices=True)
            last = k == len(ts.segments) - 1
            if len(common) != len(s.t):
                # the steps differ (an integrator's first and largest step depend on the distance to
                # t_end; an event located to event_tol): the shorter run's samples against the longer
                # run's dense output at the same times, to the integration's accuracy
                raw = long.segments[k]
                inside = s.t[(s.t >= raw.t[0]) & (s.t <= raw.t[-1])]
                if not last and len(inside) < len(s.t) and s.t[-1] - raw.t[-1] > 1e-9:
                    problems.append(f"{kind}: segment {k} ({s.configuration}) ends at {s.t[-1]:.9g} s, "
                                    f"in the longer run at {raw.t[-1]:.9g} s")
                dense = raw.resampled(inside)
                j_s = np.searchsorted(s.t, inside)
                pairs = [(getattr(s, name)[j_s], getattr(dense, name), name) for name in _SERIES]
                problems += _differ(f"{kind}: segment {k} ({s.configuration})", inside, pairs, rel_dense,
                                    ", the longer run's dense output")
            problems += _differ(f"{kind}: segment {k} ({s.configuration})", common,
                                [(getattr(s, name)[i_s], getattr(l, name)[i_l], name) for name in _SERIES], rel)
        if kind == "dt":
            problems += compare_csv(ts.to_csv(folder / "short.csv"), tl.to_csv(folder / "long.csv"), rel)
    return problems


def check_resampled_states(scene_path, t_end: float, dt: float, rel: float = 1e-6, **options) -> list[str]:
    """The ``dt`` resampling of a run must follow the solution between its steps: compared with a
    second run whose steps are at most ``dt / 8`` (and tolerances 100 times tighter), sampled at
    the same times, on segments that exist in both (the same events)."""
    import pcmm
    scene = pcmm.load_scene(scene_path)
    a = pcmm.simulate(scene, pcmm.RunOptions(t_end=t_end, **options)).resampled(dt)
    s = scene.solver
    b = pcmm.simulate(scene, pcmm.RunOptions(t_end=t_end, max_step=dt / 8, rtol=s.rtol / 100, atol=s.atol / 100,
                                             **options)).resampled(dt)
    problems = []
    if [x.configuration for x in a.segments] != [x.configuration for x in b.segments]:
        return [f"the finer run visits other configurations: {[x.configuration for x in b.segments][:6]}"]
    for k, (sa, sb) in enumerate(zip(a.segments, b.segments)):
        inner_a, inner_b = sa.t[1:-1], sb.t[1:-1]  # the grid times (the ends are the events')
        common, ia, ib = np.intersect1d(inner_a, inner_b, return_indices=True)
        problems += _differ(f"segment {k} ({sa.configuration}) resampled", common,
                            [(getattr(sa, name)[1:-1][ia], getattr(sb, name)[1:-1][ib], name)
                             for name in ("q", "v", "kinetic")], rel)
    return problems


def check_records(traj, folder: Path, stats: bool = True) -> list[str]:
    """The run's other records against its series: the CSV (one column per link quantity,
    coordinate, force element, constraint row and energy; empty where a segment lacks the name) and
    ``stats["holding"]`` (each hold's extremes along the run, and their times: at or beyond the
    samples' extremes, and each either a sample's or the force on the dense output at its time;
    not for a resampled trajectory, which keeps the run's stats)."""
    problems = []
    header, rows = _csv_rows(traj.to_csv(folder / "records.csv"))
    table = [r for t in sorted(rows) for r in rows[t]]
    if len(table) != len(traj.t):
        return [f"CSV has {len(table)} rows, the run {len(traj.t)} samples"]
    order = np.argsort(traj.t, kind="stable")
    expected = {"t": traj.t}
    for link in traj.links:
        xy = traj.series("xy", link)
        expected.update({f"theta_{link}": traj.series("theta", link), f"omega_{link}": traj.series("omega", link),
                         f"x_{link}": xy[:, 0], f"y_{link}": xy[:, 1]})
    for c in dict.fromkeys(c for s in traj.segments for c in s.coordinates):
        expected.update({f"q_{c}": traj.series("q", c), f"v_{c}": traj.series("v", c)})
    for n in dict.fromkeys(n for s in traj.segments for n in s.force_names):
        expected[f"force_{n}"] = traj.series("forces", n)
    for n in dict.fromkeys(n for s in traj.segments for n in s.constraint_labels):
        expected[f"constraint_{n}"] = traj.series("constraint_forces", n)
    expected.update({"kinetic_energy": traj.series("kinetic"), "potential_energy": traj.series("potential")})
    names = {h.rsplit(" [", 1)[0]: c for c, h in enumerate(header)}
    missing = sorted(set(expected) - set(names))
    if missing:
        problems.append(f"CSV lacks columns {missing}")
    for name, series in expected.items():
        if name not in names:
            continue
        col = np.array([float(r[names[name]]) if r[names[name]] != "" else np.nan for r in table])
        want = np.asarray(series, float)[order]
        same = (np.isnan(col) & np.isnan(want)) | (col == want)
        if not np.all(same):
            i = int(np.flatnonzero(~same)[0])
            problems.append(f"CSV column {name} at t = {traj.t[order][i]:.9g} s: "
                            f"{col[i]!r}, the series {want[i]!r}")
    config = [r[1] for r in table]
    if config != [traj.configuration_at()[i] for i in order]:
        problems.append("CSV configuration column differs from the segments'")
    for label, ext in ((traj.stats.get("holding") or {}) if stats else {}).items():
        if "normal" in ext:  # a point held by compression only: its stance force's parts
            problems += _stance_extremes(traj, label, ext)
            continue
        series = traj.series("constraint_forces", label)
        problems += _extreme_problems(traj, f"stats holding {label}", ext, series, label,
                                      lambda rec, label=label: rec.constraint_forces[:, rec.constraint_labels.index(label)])
    return problems


def _extreme_problems(traj, what: str, ext: dict, series, label: str, of_record) -> list[str]:
    """``ext`` ({min, t_min, max, t_max}) against ``series`` (over ``traj.t``): at or beyond its extremes
    (by at most 2 % of their size: a peak between two steps), and each either a sample's value at its
    time or ``of_record`` of the record at its time on the dense output of the segment holding it
    (one recording ``label``)."""
    lo, hi = float(np.nanmin(series)), float(np.nanmax(series))
    scale = max(1.0, abs(lo), abs(hi))
    problems = []
    if not (lo - 0.02 * scale <= ext["min"] <= lo + 1e-12 * scale and hi - 1e-12 * scale <= ext["max"] <= hi + 0.02 * scale):
        problems.append(f"{what}: ({ext['min']}, {ext['max']}), the series' extremes ({lo}, {hi})")
    for key in ("min", "max"):
        value, t = ext[key], ext[f"t_{key}"]
        if np.any((traj.t == t) & (series == value)):
            continue
        segs = [s for s in traj.segments if s.t[0] <= t <= s.t[-1] and label in s.constraint_labels]
        if not segs or segs[0].__dict__.get("_resample") is None:
            problems.append(f"{what}: {key} {value} at t = {t}: no sample's, and no dense output to read it on")
            continue
        dense = float(np.asarray(of_record(segs[0].resampled(np.array([t]))))[0])
        if not abs(dense - value) <= 1e-12 * scale:
            problems.append(f"{what}: {key} {value} at t = {t}, the dense output's {dense}")
    return problems


def _stance_extremes(traj, name: str, ext: dict) -> list[str]:
    """``stats["holding"][name]`` of a point held by compression only against the extremes of
    n . F and t . F (t = (n_y, -n_x)) over the samples, F the series ``name.fx``, ``name.fy``, n the
    cut joint's normal (recorded in the views, in link a's frame) turned by link a's angle."""
    joint = next(j for c in traj.views["configurations"].values() for j in c.get("cut_joints", ())
                 if j["name"] == name and j.get("normal") is not None)
    F = np.column_stack([traj.series("constraint_forces", f"{name}.{x}") for x in ("fx", "fy")])
    angle = traj.series("theta", joint["a"]) if joint["a"] in traj.links else np.zeros(len(traj.t))
    n0 = np.asarray(joint["normal"], float) / np.linalg.norm(joint["normal"])
    n = np.column_stack([np.cos(angle) * n0[0] - np.sin(angle) * n0[1], np.sin(angle) * n0[0] + np.cos(angle) * n0[1]])
    problems = []

    def parts_of(rec):
        a = rec.theta[:, rec.links.index(joint["a"])] if joint["a"] in rec.links else np.zeros(len(rec.t))
        nx, ny = np.cos(a) * n0[0] - np.sin(a) * n0[1], np.sin(a) * n0[0] + np.cos(a) * n0[1]
        f = rec.constraint_forces[:, [rec.constraint_labels.index(f"{name}.{x}") for x in ("fx", "fy")]]
        return nx * f[:, 0] + ny * f[:, 1], ny * f[:, 0] - nx * f[:, 1]

    for k, (part, series) in enumerate((("normal", np.sum(n * F, axis=1)), ("tangential", n[:, 1] * F[:, 0] - n[:, 0] * F[:, 1]))):
        problems += _extreme_problems(traj, f"stats holding {name} ({part})", ext[part], series, f"{name}.fx",
                                      lambda rec, k=k: parts_of(rec)[k])
    return problems
