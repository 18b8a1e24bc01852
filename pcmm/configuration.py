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
* the points the scene uses (contact points, cut-joint points) become
  operational frames; no other geometry or collision pair is modelled.

Models are built when a run first reaches the configuration (:class:`Mechanism`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin
import scipy.linalg as sla

from .errors import ModelError, SimulationError
from .forces import ForceField, compile_forces
from .scene import ConfigurationSpec, Measure, Scene, Target
from .urdf import dynamics_xml

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


def frame_jacobian(model, data, frame_id: int, ref=LWA) -> np.ndarray:
    """6 x nv frame Jacobian (eigenpy returns a 1-D array when nv = 1; Pinocchio
    4.1 crashes on a model with nv = 0, so that case never reaches it)."""
    if model.nv == 0:
        return np.zeros((6, 0))
    return np.asarray(pin.getFrameJacobian(model, data, frame_id, ref)).reshape(6, model.nv)


def mass_matrix(model, data, q_pin) -> np.ndarray:
    """D(q) of Eq. 1 by CRBA, symmetrized (CRBA fills the upper triangle only)."""
    M = pin.crba(model, data, q_pin)
    return np.triu(M) + np.triu(M, 1).T


def cholesky(M: np.ndarray, configuration: str):
    """Cholesky factor of a mass matrix, or a clear error when it is not positive definite."""
    try:
        return sla.cho_factor(M)
    except np.linalg.LinAlgError:
        raise SimulationError(
            f"configuration '{configuration}': the mass matrix is not positive definite (a link without "
            "mass or inertia?); every moving link needs <inertial> with mass > 0") from None


def joint_jacobian(model, data, joint_id: int, ref) -> np.ndarray:
    if model.nv == 0:
        return np.zeros((6, 0))
    return np.asarray(pin.getJointJacobian(model, data, joint_id, ref)).reshape(6, model.nv)


@dataclass(frozen=True)
class Point:
    """A point fixed on a link, registered as an operational frame."""

    link: str
    local: tuple[float, float]
    frame_id: int


class Configuration:
    def __init__(self, scene: Scene, spec: ConfigurationSpec):
        self.scene = scene
        self.spec = spec
        self.name = spec.name
        try:
            model = pin.buildModelFromXML(dynamics_xml(spec.urdf))
        except Exception as exc:  # Pinocchio's own parser errors are C++ messages
            raise ModelError(f"{spec.urdf}: Pinocchio could not build the model: {exc}") from None
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
        for t in scene.transitions_from(self.name):
            self.point(t.contact.a, t.contact.point_a)
            self.point(t.contact.b, t.contact.point_b)
        for cj in spec.cut_joints:
            self.point(cj.a, cj.point_a)
            self.point(cj.b, cj.point_b)
        self.data = model.createData()
        self._angle_map()
        self.forces: ForceField = compile_forces(scene.forces_in(self.name), self.measure_row,
                                                 self.target_column, self.nv)
        from .constraints import coordinates_for  # loops and drives, or the plain tree
        self.coords = coordinates_for(self)

    # ---- points ---------------------------------------------------------------------
    def point(self, link: str, local) -> Point:
        """The operational frame of ``local`` (x, y) on ``link``; created on first use."""
        key = (link, (float(local[0]), float(local[1])))
        if key in self._points:
            return self._points[key]
        if hasattr(self, "data"):
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

    def vector(self, values: dict[str, float | tuple]) -> np.ndarray:
        """A coordinate vector from {joint name: value}; a planar joint takes (x, y, theta)."""
        out = np.zeros(self.nv)
        for name, val in values.items():
            out[self.joint_slice[name]] = val
        return out

    def by_joint(self, x: np.ndarray) -> dict[str, float | list[float]]:
        out = {}
        for name in self.joint_names:
            sl = self.joint_slice[name]
            vals = x[sl]
            out[name] = float(vals[0]) if vals.size == 1 else [float(u) for u in vals]
        return out

    # ---- angles ------------------------------------------------------------------------
    def _angle_map(self) -> None:
        """theta_link = A q + b, exact because every rotation axis is normal to the plane."""
        q0 = self.to_pin(self.neutral())
        pin.computeJointJacobians(self.model, self.data, q0)
        pin.updateFramePlacements(self.model, self.data)
        self.A = np.zeros((len(self.links), self.nv))
        self.b = np.zeros(len(self.links))
        for i, link in enumerate(self.links):
            fid = self.link_frame[link]
            J = frame_jacobian(self.model, self.data, fid)
            self.A[i] = J[5]
            R = self.data.oMf[fid].rotation
            self.b[i] = np.arctan2(R[1, 0], R[0, 0])
        self.link_index = {link: i for i, link in enumerate(self.links)}

    def link_angles(self, q: np.ndarray) -> np.ndarray:
        return self.A @ q + self.b

    def measure_row(self, m: Measure) -> tuple[np.ndarray, float]:
        """(row, offset) with measure = row . q + offset, and its rate = row . v."""
        if m.kind == "joint":
            row = np.zeros(self.nv)
            row[self.joint_slice[m.names[0]].start] = 1.0
            return row, 0.0
        idx = [self.link_index[n] for n in m.names]
        if m.kind == "link":
            return self.A[idx[0]].copy(), float(self.b[idx[0]])
        return self.A[idx[1]] - self.A[idx[0]], float(self.b[idx[1]] - self.b[idx[0]])

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

    def potential_energy(self, q: np.ndarray) -> float:
        """Gravity plus spring energy (J).

        Bodies welded to the frame (a link merged with it, like a slider at its stop) sit in
        Pinocchio's universe inertia, which ``computePotentialEnergy`` leaves out; their constant
        share is added so the potential energy is continuous across a configuration switch."""
        fixed = self.model.inertias[0]
        welded = -fixed.mass * float(self.model.gravity.linear @ fixed.lever)
        return float(pin.computePotentialEnergy(self.model, self.data, self.to_pin(q))) \
            + welded + self.forces.potential_energy(q)

    def link_poses(self, q: np.ndarray) -> np.ndarray:
        """(nlinks, 3): x, y, theta of every link frame; needs no prior call."""
        pin.framesForwardKinematics(self.model, self.data, self.to_pin(q))
        th = self.link_angles(q)
        out = np.empty((len(self.links), 3))
        for i, link in enumerate(self.links):
            out[i, :2] = self.data.oMf[self.link_frame[link]].translation[:2]
            out[i, 2] = th[i]
        return out


class Mechanism:
    """All configurations of a scene, each built when the run first reaches it."""

    def __init__(self, scene: Scene):
        self.scene = scene
        self._built: dict[str, Configuration] = {}

    def __getitem__(self, name: str) -> Configuration:
        if name not in self._built:
            self._built[name] = Configuration(self.scene, self.scene.configurations[name])
        return self._built[name]

    @property
    def built(self) -> tuple[str, ...]:
        return tuple(self._built)
