"""Run results: segments (one per stay in a configuration), events and stats.

A :class:`Trajectory` saves to one NPZ file (arrays plus a JSON header) and
loads back without the scene; it exports CSV with one column per named
quantity and units in the header.  Files are written atomically (temporary
file, then rename) so an interrupted write never leaves half a file.
"""
from __future__ import annotations

import json
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import UsageError

_ARRAYS = ("t", "q", "v", "theta", "omega", "xy", "kinetic", "potential", "forces", "constraint_forces")


@dataclass
class SegmentRecord:
    """Samples of one stay in one configuration (the integrator's steps)."""

    configuration: str
    coordinates: list[str]  # one name per velocity: "O1", or "P.x", "P.y", "P.theta"
    links: list[str]
    force_names: list[str]
    constraint_labels: list[str]
    t: np.ndarray
    q: np.ndarray  # (n, nv)
    v: np.ndarray  # (n, nv)
    theta: np.ndarray  # (n, nlinks) absolute angles, continuous across switches
    omega: np.ndarray  # (n, nlinks)
    xy: np.ndarray  # (n, nlinks, 2) link frame origins
    kinetic: np.ndarray  # (n,)
    potential: np.ndarray  # (n,) gravity + springs
    forces: np.ndarray  # (n, nforces) each force element's output (N or N m)
    constraint_forces: np.ndarray  # (n, m) cut-joint reactions and driving moments


@dataclass
class Trajectory:
    scene: str  # path of the scene file
    scene_name: str
    impact: bool  # False: the comparison run without impact (Figs. 6-9)
    segments: list[SegmentRecord] = field(default_factory=list)
    events: list[dict] = field(default_factory=list)
    stats: dict = field(default_factory=dict)
    status: str = "complete"  # or "partial"
    message: str = ""

    # ---- access -----------------------------------------------------------------------
    @property
    def t(self) -> np.ndarray:
        return np.concatenate([s.t for s in self.segments]) if self.segments else np.zeros(0)

    @property
    def links(self) -> list[str]:
        out: list[str] = []
        for s in self.segments:
            out += [n for n in s.links if n not in out]
        return out

    def series(self, quantity: str, name: str | None = None) -> np.ndarray:
        """A quantity over the whole run (NaN where a segment lacks ``name``).

        ``quantity``: ``theta``/``omega`` (by link), ``q``/``v`` (by coordinate),
        ``forces`` (by force name), ``constraint_forces`` (by row label),
        ``kinetic``/``potential`` (no name)."""
        names_of = {"theta": "links", "omega": "links", "xy": "links", "q": "coordinates",
                    "v": "coordinates", "forces": "force_names", "constraint_forces": "constraint_labels"}
        parts = []
        for s in self.segments:
            arr = getattr(s, quantity)
            if quantity in names_of:
                names = getattr(s, names_of[quantity])
                if name in names:
                    parts.append(arr[:, names.index(name)])
                else:
                    parts.append(np.full((len(s.t),) + arr.shape[2:], np.nan))
            else:
                parts.append(arr)
        return np.concatenate(parts) if parts else np.zeros(0)

    def configuration_at(self) -> list[str]:
        return [s.configuration for s in self.segments for _ in s.t]

    # ---- files ------------------------------------------------------------------------
    def save(self, path: str | Path, force: bool = True) -> Path:
        header = {"format": "pcmm-trajectory-1", "scene": self.scene, "scene_name": self.scene_name,
                  "impact": self.impact, "events": self.events, "stats": self.stats,
                  "status": self.status, "message": self.message,
                  "segments": [{"configuration": s.configuration, "coordinates": s.coordinates,
                                "links": s.links, "force_names": s.force_names,
                                "constraint_labels": s.constraint_labels} for s in self.segments]}
        arrays = {"header": np.array(json.dumps(header, default=_json_default))}
        for i, s in enumerate(self.segments):
            for a in _ARRAYS:
                arrays[f"s{i}_{a}"] = getattr(s, a)

        def write(f):
            np.savez_compressed(f, **arrays)
        return atomic_write(path, write, force=force, binary=True)

    @classmethod
    def load(cls, path: str | Path) -> "Trajectory":
        path = Path(path)
        try:
            with np.load(path, allow_pickle=False) as z:
                header = json.loads(str(z["header"]))
                if header.get("format") != "pcmm-trajectory-1":
                    raise ValueError("not a pcmm trajectory")
                segs = []
                for i, meta in enumerate(header["segments"]):
                    segs.append(SegmentRecord(**meta, **{a: z[f"s{i}_{a}"] for a in _ARRAYS}))
        except FileNotFoundError:
            raise UsageError(f"{path}: trajectory file not found") from None
        except (OSError, ValueError, KeyError) as exc:
            raise UsageError(f"{path}: not a pcmm trajectory file (.npz written by 'pcmm run --out'): {exc}") from None
        return cls(scene=header["scene"], scene_name=header["scene_name"], impact=header["impact"],
                   segments=segs, events=header["events"], stats=header["stats"],
                   status=header["status"], message=header["message"])

    def to_csv(self, path: str | Path, force: bool = True) -> Path:
        """One row per sample; columns: t, configuration, then named quantities with units."""
        cols: list[tuple[str, np.ndarray]] = [("t [s]", self.t)]
        for link in self.links:
            cols.append((f"theta_{link} [rad]", self.series("theta", link)))
            cols.append((f"omega_{link} [rad/s]", self.series("omega", link)))
            xy = self.series("xy", link)
            cols.append((f"x_{link} [m]", xy[:, 0]))
            cols.append((f"y_{link} [m]", xy[:, 1]))
        coords = []
        for s in self.segments:
            coords += [c for c in s.coordinates if c not in coords]
        for c in coords:
            cols.append((f"q_{c} [rad|m]", self.series("q", c)))
            cols.append((f"v_{c} [rad/s|m/s]", self.series("v", c)))
        for name in dict.fromkeys(n for s in self.segments for n in s.force_names):
            cols.append((f"force_{name} [N m|N]", self.series("forces", name)))
        for name in dict.fromkeys(n for s in self.segments for n in s.constraint_labels):
            cols.append((f"constraint_{name} [N|N m]", self.series("constraint_forces", name)))
        cols.append(("kinetic_energy [J]", self.series("kinetic")))
        cols.append(("potential_energy [J]", self.series("potential")))
        config = self.configuration_at()

        def write(f):
            f.write(",".join(["t [s]", "configuration"] + [c[0] for c in cols[1:]]) + "\n")
            data = np.column_stack([c[1] for c in cols]) if cols else np.zeros((0, 0))
            for i, row in enumerate(data):
                f.write(f"{float(row[0])!r},{config[i]}," + ",".join("" if np.isnan(x) else repr(float(x))
                                                             for x in row[1:]) + "\n")
        return atomic_write(path, write, force=force)


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    raise TypeError(f"not JSON serializable: {type(o)}")


def atomic_write(path: str | Path, write, force: bool, binary: bool = False) -> Path:
    """Write via a temporary file in the same folder, then rename."""
    path = Path(path)
    if path.exists() and not force:
        raise UsageError(f"{path}: exists; pass --force to overwrite it")
    if not path.parent.exists():
        raise UsageError(f"{path}: folder {path.parent} does not exist")
    if path.is_dir():
        raise UsageError(f"{path}: is a folder; give a file name")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; give the file the mode an ordinary open would
    try:
        with os.fdopen(fd, "wb" if binary else "w", **({} if binary else {"encoding": "utf-8"})) as f:
            write(f)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def dumps_json(obj) -> str:
    return json.dumps(obj, indent=2, default=_json_default)
