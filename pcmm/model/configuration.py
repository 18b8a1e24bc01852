"""A configuration: one URDF (a tree) plus what the scene says about it.

Between transformations a configuration is an ordinary mechanism,
``D(q) q'' + H = tau_a + tau_c`` (paper Eq. 1).  Pinocchio supplies D (CRBA),
H (RNEA/ABA) and frame Jacobians; this module adds the planar bookkeeping:

* pcmm's coordinates ``q`` have one entry per velocity (``nq = nv``): a URDF
  ``planar`` joint is ``(x, y, theta)``, converted to Pinocchio's
  ``(x, y, cos, sin)`` by :meth:`Configuration.to_pin`; velocities are
  Pinocchio's own (a planar joint's are in its local frame).
* every link's absolute angle is linear in ``q``: ``theta = A q + b``
  (all axes are normal to the plane), so angles never wrap.
* the points the scene uses (contact points, cut-joint points, point-spring ends) become
  operational frames; no other geometry or collision pair is modelled.

Models are built when a run first reaches the configuration (:class:`pcmm.mechanism.Mechanism`),
once per process for each URDF text, set of points and gravity (later runs reuse them).
"""
from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import pinocchio as pin

from ..errors import ModelError
from .coordinates import Coordinates
from .forces import ForceField, compile_forces, compile_point_springs
from .pinocchio_helpers import LWA, frame_jacobian, mass_matrix
from ..scene.spec import ConfigurationSpec, Measure, Scene, Target
from ..scene.urdf import dynamics_xml

#: a planar joint's coordinates, named "P.x", "P.y", "P.theta" (series, CSV, [initial] independent)
PLANAR_PARTS = ("x", "y", "theta")


@dataclass(frozen=True)
class Point:
    """A point fixed on a link, registered as an operational frame."""

    link: str
    local: tuple[float, float]
    frame_id: int


class _Built(threading.local):
    """This thread's built models (Pinocchio's Data is scratch space, never shared between threads):
    ``models = {(URDF text, points, gravity): the model's fields Configuration.__init__ reuses}``."""

    def __init__(self):
        self.models: dict = {}


_BUILT = _Built()
_WORKSPACE_LOCK = threading.Lock()  # guards the creation of a thread's Data (Configuration.workspace)
_BUILT_MAX = 16  # models kept per thread (a large chain's Data holds nv^3-sized tensors)
_FORCES_KEPT = 16  # compiled force elements kept per model (a sweep over a torque makes a key per row)


def _point_keys(scene: Scene, spec: ConfigurationSpec) -> tuple:
    """The points a configuration registers as frames, in registration order: the contact
    points of every transition whose two links it has (not only of those leaving it: a holding
    force is computed on a configuration with the held joints free, which need not be the one
    the stop left), its cut joints' points and its point springs' ends."""
    links = set(spec.info.links)
    keys = []
    for t in scene.transitions:
        c = t.contact
        if c is not None and c.joint is None and c.a in links and c.b in links:
            keys += [(c.a, tuple(c.point_a)), (c.b, tuple(c.point_b))]
    for cj in spec.cut_joints:
        keys += [(cj.a, tuple(cj.point_a)), (cj.b, tuple(cj.point_b))]
    for f in scene.forces_in(spec.name):
        if f.points is not None:
            keys += [(f.points.a, tuple(f.points.point_a)), (f.points.b, tuple(f.points.point_b))]
    return tuple((link, (float(p[0]), float(p[1]))) for link, p in keys)


def _angle_map(model, data, frames) -> tuple[np.ndarray, np.ndarray]:
    """(A, b) with the absolute angles of the links at ``frames`` = ``A q + b`` as Pinocchio's
    model has them: ``A`` the rows of their angular-velocity Jacobians, ``b`` their angles in the
    neutral posture read from their rotations, so only modulo 2 pi (in (-pi, pi])."""
    pin.computeJointJacobians(model, data, pin.neutral(model))
    pin.updateFramePlacements(model, data)
    A = np.zeros((len(frames), model.nv))
    b = np.zeros(len(frames))
    for i, fid in enumerate(frames):
        A[i] = frame_jacobian(model, data, fid)[5]
        R = data.oMf[fid].rotation
        b[i] = np.arctan2(R[1, 0], R[0, 0])
    return A, b


def _written_angles(info, links, turned) -> np.ndarray:
    """Each link's angle in the neutral posture as the URDF writes it: the sum of the joint
    origins' yaws from the root, plus the value of every revolute joint in ``turned`` on the way
    (a derived configuration's locks).  A planar URDF has no roll or pitch and its revolute axes
    are +z (the URDF check refuses others), so this is exact, with no branch to pick."""
    parent_of = {j.child: j for j in info.joints.values()}
    out = np.zeros(len(links))
    for i, link in enumerate(links):
        while link in parent_of:
            joint = parent_of[link]
            out[i] += joint.rpy[2] + turned.get(joint.name, 0.0)
            link = joint.parent
    return out


def check_point_masses(model, data, spec: ConfigurationSpec, planar, link_frame) -> None:
    """A link may be a point mass (an all-zero ``<inertia>``) where the mass matrix stays positive
    definite: probed at the neutral posture and at five seeded ones (smallest eigenvalue above
    1e-12 times the largest).  Otherwise the configuration is refused, naming the link."""
    points = [link for link, f in link_frame.items() if model.frames[f].parentJoint > 0
              and model.inertias[model.frames[f].parentJoint].mass > 0
              and model.inertias[model.frames[f].parentJoint].inertia[2, 2] <= 0.0]
    if not points or model.nv == 0:
        return
    rng = np.random.default_rng(0)
    for k in range(6):
        q = pin.neutral(model) if k == 0 else pin.randomConfiguration(
            model, -np.pi * np.ones(model.nq), np.pi * np.ones(model.nq))
        if k and planar:  # a planar joint's (cos, sin) must stay a unit vector
            for iq, _ in planar:
                a = rng.uniform(-np.pi, np.pi)
                q[iq + 2:iq + 4] = (np.cos(a), np.sin(a))
        M = pin.crba(model, data, q)
        eig = np.linalg.eigvalsh(np.triu(M) + np.triu(M, 1).T)
        if eig[0] <= 1e-12 * eig[-1]:
            free = [link for link in points if model.joints[model.frames[link_frame[link]].parentJoint].nq == 4]
            why = (f"link(s) {free} are point masses on a free (planar) joint: their rotation is determined only "
                   "by cut joints, and the tree's mass matrix is singular; give them a rotational inertia"
                   if free else f"with the point mass(es) {points} the mass matrix is singular (smallest "
                   f"eigenvalue {eig[0]:.3g}, largest {eig[-1]:.3g}): a point mass on the axis of its own joint "
                   "has nothing to turn; give it a rotational inertia or move it off the axis")
            raise ModelError(f"{spec.source}: configuration '{spec.name}': {why}")


class Configuration:
    """One configuration's model and bookkeeping.

    ``coordinates(cfg)`` builds the coordinate strategy the configuration integrates in
    (:func:`pcmm.constraints.coordinates_for`: a plain tree, or loops and drives by
    partitioning); it is given by the caller (:class:`pcmm.mechanism.Mechanism`) so this
    module needs nothing from the layers above it.
    """

    def __init__(self, scene: Scene, spec: ConfigurationSpec, coordinates: Callable[[Configuration], Coordinates]):
        self.scene = scene
        self.spec = spec
        self.name = spec.name
        self._coordinates = coordinates
        self._owner = threading.get_ident()  # the thread whose Data (``_data``) this model was built with
        self._workspaces: dict[int, object] = {}  # {thread id: Data} of the other threads (workspace)
        self._angle_offsets: dict[str, float] = {}  # {link: 2 pi k} of the run's series (continue_angles)
        # The Pinocchio model and data are built once per process (and thread) for each URDF text, set
        # of points and gravity, and reused by every later run: Pinocchio 4.1's createData allocates
        # nv^3-sized tensors (29 ms at nv = 100), more than a whole run of a small mechanism.
        try:  # a derived configuration's model is its own URDF text, not its base file's
            text = spec.xml.encode() if spec.xml is not None else Path(spec.urdf).read_bytes()
        except OSError as exc:
            raise ModelError(f"{spec.urdf}: cannot read the URDF: {exc.strerror or exc}") from None
        key = (text, _point_keys(scene, spec), tuple(scene.gravity))
        cache = _BUILT.models
        built = cache.get(key)
        if built is not None:
            self.__dict__.update(built)
            self._after_model()
            return
        try:
            model = pin.buildModelFromXML(dynamics_xml(spec.urdf, spec.xml))
        except Exception as exc:  # Pinocchio's own parser errors are C++ messages
            raise ModelError(f"{spec.source}: Pinocchio could not build the model: {exc}") from None
        model.gravity.linear[:] = [scene.gravity[0], scene.gravity[1], 0.0]
        self.model = model
        self.nv = model.nv
        # movable joints in velocity order
        self.joint_names: list[str] = []
        self.joint_slice: dict[str, slice] = {}
        self.joint_id: dict[str, int] = {}
        self._planar: list[tuple[int, int]] = []  # (idx_q, idx_v) of planar joints
        for jid in range(1, model.njoints):
            j = model.joints[jid]
            name = model.names[jid]
            self.joint_names.append(name)
            self.joint_slice[name] = slice(j.idx_v, j.idx_v + j.nv)
            self.joint_id[name] = jid
            if j.nq != j.nv:
                self._planar.append((j.idx_q, j.idx_v))
        self.links: tuple[str, ...] = tuple(spec.info.links)
        self.link_frame = {}
        for link in self.links:
            if not model.existFrame(link, pin.FrameType.BODY):
                raise ModelError(f"{spec.urdf}: link '{link}' has no body frame in Pinocchio's model")
            self.link_frame[link] = model.getFrameId(link, pin.FrameType.BODY)
        self.root = spec.info.root
        self._points: dict[tuple[str, tuple[float, float]], Point] = {}
        for link, xy in key[1]:
            self.point(link, xy)
        self._data = model.createData()
        # the constant potential energy of the bodies welded to the frame (gravity_energy)
        fixed = model.inertias[0]
        self._welded_energy = -fixed.mass * float(model.gravity.linear @ fixed.lever)
        check_point_masses(model, self.data, spec, self._planar, self.link_frame)
        self._angle_map()
        self.cut_models: dict = {}  # cut systems by cut joints (pcmm.events.cutting), built on first impact
        self._forces_compiled: dict = {}  # force elements by (their specs, angle offsets): _compile_forces
        self.impulse_models: dict = {}  # event-path constants: the zero-gravity copy for joint impulses, link joints (pcmm.events.impulse), the frame pivot (pcmm.events.momentum)
        if len(cache) >= _BUILT_MAX:
            cache.pop(next(iter(cache)))
        cache[key] = {k: self.__dict__[k] for k in (
            "model", "nv", "joint_names", "joint_slice", "joint_id", "_planar", "links", "link_frame", "root",
            "_points", "_data", "_welded_energy", "A", "b", "link_index", "cut_models", "impulse_models", "_forces_compiled")}
        self._after_model()

    @property
    def data(self):
        """The calling thread's Pinocchio ``Data`` for this model (:meth:`workspace`)."""
        if threading.get_ident() == self._owner:
            return self._data
        return self.workspace()

    def workspace(self):
        """The calling thread's Pinocchio ``Data``: scratch space that every evaluation writes, so
        never shared between threads.  The thread that built the configuration has the one it was
        built with; any other (a trajectory's lazy series read elsewhere) gets one of its own,
        created on first use and kept."""
        ident = threading.get_ident()
        if ident == self._owner:
            return self._data
        with _WORKSPACE_LOCK:
            data = self._workspaces.get(ident)
            if data is None:
                data = self._workspaces[ident] = self.model.createData()
        return data

    def _after_model(self) -> None:
        """What depends on the scene beyond the model: force elements and coordinates."""
        self.forces: ForceField = self._compile_forces()
        self.coords: Coordinates = self._coordinates(self)  # loops and drives, or the plain tree

    def _compile_forces(self) -> ForceField:
        """The force elements of this configuration at its angle offsets.  Without point springs
        they are a function of their specs, the offsets and the model alone: compiled once per
        process (and thread) and shared by every run of the model, every later run of a scene
        (a sweep's, a comparison run's) taking them as they are (a ForceField is frozen and
        nothing writes its arrays)."""
        forces = self.scene.forces_in(self.name)
        if all(f.points is None for f in forces):
            try:
                key = (forces, self.angle_offsets)
                compiled = self._forces_compiled.get(key)
            except TypeError:  # a spec's value that is not hashable: compiled for this run
                key = compiled = None
            if compiled is None:
                compiled = compile_forces(forces, self.measure_row, self.target_column, self.nv)
                if key is not None:
                    if len(self._forces_compiled) >= _FORCES_KEPT:
                        self._forces_compiled.pop(next(iter(self._forces_compiled)))
                    self._forces_compiled[key] = compiled
            return compiled
        points = compile_point_springs(forces, self.model, self.to_pin,
                                       lambda link, xy: self.point(link, xy).frame_id)
        return compile_forces(forces, self.measure_row, self.target_column, self.nv, points)

    @property
    def angle_offsets(self) -> tuple[tuple[str, float], ...]:
        """The run's offsets {link: 2 pi k} its measures read the link angles with, as sorted pairs."""
        return tuple(sorted(self._angle_offsets.items()))

    def continue_angles(self, offsets: dict[str, float]) -> None:
        """Measure link angles as the run's series give them: ``A q + b`` plus the run's offset
        {link: 2 pi k} of each link.  A configuration entered from another may write a link's angle
        on another 2 pi branch than the run arrived at (a hand-written URDF with a joint yaw of -pi
        where the run came to +pi: the same posture); the series continue across the switch
        (:func:`pcmm.transitions.pose_mismatches`), and so must every measure read off these
        angles: a torsion spring's deflection, a coordinate guard.  Without this, the spring across
        such a joint pushed with k 2 pi more after the switch.  Force elements are compiled again
        where the offsets change."""
        mine = {link: float(d) for link, d in offsets.items() if link in self.link_index and d != 0.0}
        if mine == self._angle_offsets:
            return
        self._angle_offsets = mine
        self.forces = self._compile_forces()
        self.coords.forces_changed()

    # ---- points ---------------------------------------------------------------------
    def point(self, link: str, local) -> Point:
        """The operational frame of ``local`` (x, y) on ``link``; created on first use."""
        key = (link, (float(local[0]), float(local[1])))
        if key in self._points:
            return self._points[key]
        if hasattr(self, "_data"):
            raise RuntimeError("points must be registered before the model's data are created")
        parent = self.model.frames[self.link_frame[link]]
        placement = parent.placement * pin.SE3(np.eye(3), np.array([key[1][0], key[1][1], 0.0]))
        name = f"pcmm:{link}@{key[1][0]:.9g},{key[1][1]:.9g}"
        fid = self.model.addFrame(pin.Frame(name, parent.parentJoint, self.link_frame[link], placement,
                                            pin.FrameType.OP_FRAME))
        self._points[key] = Point(link, key[1], fid)
        return self._points[key]

    # ---- coordinates -----------------------------------------------------------------------
    @property
    def has_planar(self) -> bool:
        return bool(self._planar)

    def neutral(self) -> np.ndarray:
        return np.zeros(self.nv)

    def to_pin(self, q: np.ndarray) -> np.ndarray:
        """pcmm coordinates -> Pinocchio configuration vector."""
        if not self._planar:
            return q
        out = np.empty(self.model.nq)
        iq_prev = iv_prev = 0
        for iq, iv in self._planar:
            out[iq_prev:iq] = q[iv_prev:iv]
            out[iq:iq + 4] = (q[iv], q[iv + 1], np.cos(q[iv + 2]), np.sin(q[iv + 2]))
            iq_prev, iv_prev = iq + 4, iv + 3
        out[iq_prev:] = q[iv_prev:]
        return out

    def qdot(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Time derivative of pcmm coordinates (a planar joint's velocity is local)."""
        if not self._planar:
            return v
        out = v.copy()
        for _, iv in self._planar:
            c, s = np.cos(q[iv + 2]), np.sin(q[iv + 2])
            out[iv], out[iv + 1] = c * v[iv] - s * v[iv + 1], s * v[iv] + c * v[iv + 1]
        return out

    def velocity(self, q: np.ndarray, rates: np.ndarray) -> np.ndarray:
        """The velocity ``v`` whose coordinate rates (:meth:`qdot`) are ``rates``: the inverse of
        :meth:`qdot` (``rates`` itself when there is no planar joint)."""
        if not self._planar:
            return rates
        out = rates.copy()
        for _, iv in self._planar:
            c, s = math.cos(q[iv + 2]), math.sin(q[iv + 2])
            out[iv], out[iv + 1] = c * rates[iv] + s * rates[iv + 1], -s * rates[iv] + c * rates[iv + 1]
        return out

    def qddot(self, q: np.ndarray, v: np.ndarray, a: np.ndarray) -> np.ndarray:
        """Second time derivative of pcmm coordinates from the accelerations ``a = v'``: the
        derivative of :meth:`qdot`, ``R a + theta' R' v`` for a planar joint's (x, y) (``a`` itself
        when there is no planar joint)."""
        if not self._planar:
            return a
        out = a.copy()
        for _, iv in self._planar:
            c, s, w = math.cos(q[iv + 2]), math.sin(q[iv + 2]), v[iv + 2]
            vx, vy = v[iv], v[iv + 1]
            out[iv] = c * a[iv] - s * a[iv + 1] - w * (s * vx + c * vy)
            out[iv + 1] = s * a[iv] + c * a[iv + 1] + w * (c * vx - s * vy)
        return out

    def position_jacobian(self, q: np.ndarray, J: np.ndarray) -> np.ndarray:
        """``d f / d q`` from the velocity Jacobian ``J`` of a function ``f`` of the posture
        (``f' = J v``): with ``q' = T(q) v`` (:meth:`qdot`) it is ``J T(q)^-1``.  A planar joint's
        velocity is local, ``(x', y') = R(theta) (v_x, v_y)``, so its two columns become
        ``J[:, xy] R(theta)^T``; every other column is unchanged (``J`` itself when there is no
        planar joint).  A Newton solve of ``f(q) = 0`` in pcmm's coordinates needs this matrix,
        not ``J``: with ``J`` it is off by the body's rotation and diverges once that passes 90
        degrees."""
        if not self._planar:
            return J
        out = J.copy()
        for _, iv in self._planar:
            c, s = math.cos(q[iv + 2]), math.sin(q[iv + 2])
            jx, jy = J[:, iv], J[:, iv + 1]
            out[:, iv], out[:, iv + 1] = c * jx - s * jy, s * jx + c * jy
        return out

    def vector(self, values: dict[str, float | tuple]) -> np.ndarray:
        """A coordinate vector from {joint name: value}; a planar joint takes (x, y, theta)."""
        out = np.zeros(self.nv)
        for name, val in values.items():
            out[self.joint_slice[name]] = val
        return out

    def coordinate_index(self, name: str) -> int:
        """The index in q of a coordinate named as the series name them: a joint ("J", a planar
        joint's first coordinate) or one coordinate of a planar joint ("P.x", "P.y", "P.theta")."""
        if name in self.joint_slice:
            return self.joint_slice[name].start
        joint, _, part = name.rpartition(".")
        sl = self.joint_slice[joint]
        if sl.stop - sl.start != 3 or part not in PLANAR_PARTS:
            raise KeyError(name)
        return sl.start + PLANAR_PARTS.index(part)

    def by_joint(self, x: np.ndarray) -> dict[str, float | list[float]]:
        if not self._planar and len(x) == self.nv == len(self.joint_names):  # one entry per joint, in order
            return dict(zip(self.joint_names, np.asarray(x, float).tolist()))
        out = {}
        for name in self.joint_names:
            sl = self.joint_slice[name]
            vals = x[sl]
            out[name] = float(vals[0]) if vals.size == 1 else [float(u) for u in vals]
        return out

    # ---- angles ------------------------------------------------------------------------
    def _angle_map(self) -> None:
        """theta_link = A q + b, exact because every rotation axis is normal to the plane.

        ``b`` is each link's angle in the neutral posture as the URDF writes it (a derived
        configuration: its root URDF with the locked joints' values added); the model's rotations
        confirm it modulo 2 pi.  Read from the rotations alone it would be known only modulo
        2 pi: a joint locked at pi leaves its child at exactly +-pi, where the rotation's round-off
        picks the branch, and a torsion spring across the locked joint (a relative-angle measure)
        would then act as if the joint had turned by 2 pi (silently, and differently on another
        machine).  So the angles continue those of the configuration the lock was taken in, and a
        link written at -pi is at -pi."""
        self.A, rotated = _angle_map(self.model, self.data, [self.link_frame[link] for link in self.links])
        self.link_index = {link: i for i, link in enumerate(self.links)}
        der = self.spec.derivation
        turned = {j: v for j, v in der.values if der.joints[j].type == "revolute"} if der else {}
        self.b = _written_angles(self.spec.info, self.links, turned)
        off = (rotated - self.b + np.pi) % (2 * np.pi) - np.pi
        if np.max(np.abs(off), initial=0.0) > 1e-9:  # the same posture, or the model is not the URDF's
            locks = f" with {dict(der.values)} locked" if der else ""
            raise ModelError(f"configuration '{self.name}': its links' angles in Pinocchio's model differ from "
                             f"those {self.spec.urdf}{locks} writes by up to {np.max(np.abs(off)):.3g} rad")

    def link_angles(self, q: np.ndarray) -> np.ndarray:
        return self.A @ q + self.b

    def measure_row(self, m: Measure) -> tuple[np.ndarray, float]:
        """(row, offset) with measure = row . q + offset, and its rate = row . v."""
        if m.kind == "joint":
            row = np.zeros(self.nv)
            row[self.joint_slice[m.names[0]].start] = 1.0
            return row, 0.0
        idx = [self.link_index[n] for n in m.names]
        b = [self.b[i] + self._angle_offsets.get(n, 0.0) for i, n in zip(idx, m.names)]
        if m.kind == "link":
            return self.A[idx[0]].copy(), float(b[0])
        return self.A[idx[1]] - self.A[idx[0]], float(b[1] - b[0])

    def target_column(self, t: Target) -> np.ndarray:
        if t.kind == "joint":
            col = np.zeros(self.nv)
            col[self.joint_slice[t.name].start] = 1.0
            return col
        return self.A[self.link_index[t.name]].copy()

    # ---- kinematics --------------------------------------------------------------------
    def kinematics(self, q: np.ndarray, v: np.ndarray | None = None) -> None:
        """Placements, frame placements and joint Jacobians at (q, v)."""
        qp = self.to_pin(q)
        if self.nv == 0:
            pin.framesForwardKinematics(self.model, self.data, qp)
            return
        if v is None:
            pin.computeJointJacobians(self.model, self.data, qp)
        else:
            pin.forwardKinematics(self.model, self.data, qp, v)
            pin.computeJointJacobians(self.model, self.data, qp)
        pin.updateFramePlacements(self.model, self.data)

    def point_position(self, p: Point) -> np.ndarray:
        """World (x, y) of a point; needs :meth:`kinematics` first."""
        return self.data.oMf[p.frame_id].translation[:2].copy()

    def point_jacobian(self, p: Point) -> np.ndarray:
        """2 x nv Jacobian of the point's world velocity; needs :meth:`kinematics` first."""
        return frame_jacobian(self.model, self.data, p.frame_id)[:2]

    def rotation(self, link: str) -> np.ndarray:
        return self.data.oMf[self.link_frame[link]].rotation[:2, :2].copy()

    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        if self.nv == 0:
            return np.zeros((0, 0))
        return mass_matrix(self.model, self.data, self.to_pin(q))

    def kinetic_energy(self, q: np.ndarray, v: np.ndarray) -> float:
        if self.nv == 0:
            return 0.0
        return float(pin.computeKineticEnergy(self.model, self.data, self.to_pin(q), v))

    def gravity_energy(self, q: np.ndarray) -> float:
        """Potential energy of gravity (J).

        Bodies welded to the frame (a link merged with it, like a slider at its stop) sit in
        Pinocchio's universe inertia, which ``computePotentialEnergy`` leaves out; their constant
        share is added so the potential energy is continuous across a configuration switch: a
        constant of the model (its inertia 0 and gravity, neither written after it is built),
        computed once with it (``_welded_energy``)."""
        return float(pin.computePotentialEnergy(self.model, self.data, self.to_pin(q))) + self._welded_energy

    def potential_energy(self, q: np.ndarray, forces: ForceField | None = None) -> float:
        """Gravity plus spring energy (J) of ``forces`` (a recorded segment's own, compiled at its
        angle offsets), by default the configuration's current ones."""
        return self.gravity_energy(q) + (self.forces if forces is None else forces).potential_energy(q)

    def link_velocities(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(nlinks, 3): vx, vy of every link frame's origin and its angular velocity (world)."""
        out = np.zeros((len(self.links), 3))
        if self.nv == 0:
            return out
        pin.forwardKinematics(self.model, self.data, self.to_pin(q), v)
        pin.updateFramePlacements(self.model, self.data)
        for i, link in enumerate(self.links):
            m = pin.getFrameVelocity(self.model, self.data, self.link_frame[link], LWA)
            out[i, :2], out[i, 2] = m.linear[:2], m.angular[2]
        return out

    def link_poses(self, q: np.ndarray) -> np.ndarray:
        """(nlinks, 3): x, y, theta of every link frame; needs no prior call."""
        pin.framesForwardKinematics(self.model, self.data, self.to_pin(q))
        th = self.link_angles(q)
        out = np.empty((len(self.links), 3))
        for i, link in enumerate(self.links):
            out[i, :2] = self.data.oMf[self.link_frame[link]].translation[:2]
            out[i, 2] = th[i]
        return out
