"""The paper's figures (PNG) for a run, optionally overlaid with a comparison run.

:func:`write_figures` decides the figure set from what the trajectory holds:

=============================  ==========================================  ================
file                           content                                     paper (Song 2020)
=============================  ==========================================  ================
``link_angles.png``            absolute angle of every rotating link       Fig. 6 (a-c)
``relative_angles.png``        angle between consecutive rotating links    Fig. 6 (d)
``angular_velocities.png``     angular velocity of every rotating link     Fig. 7
``force_elements.png``         each force element's output (moments)       Fig. 8
``energy.png``                 kinetic and potential energy                Figs. 9, 15
``impulses.png``               normal impulse per impact (stem plot)       Fig. 12
``slider.png``                 slider position and velocity, inset zoom    Fig. 13
                               around the first impact
``driving_moment.png``         driving moment (constraint rows "*.drive")  Fig. 14
=============================  ==========================================  ================

``impulses.png`` needs events with an impulse, ``slider.png`` a translating
link (a link whose angle never changes while its origin moves: position
along its line of motion; velocity by differentiating the recorded
positions within each segment) or prismatic coordinates, and
``driving_moment.png`` constraint forces labelled ``<joint>.drive``.

With ``compare`` (usually the run without impact) both runs are overlaid:
"Considering impact motion" (solid) and "Without considering impact motion"
(dashed), labelled by each run's ``impact`` flag.  Impact instants (the first
of each burst of impacts) are marked with a vertical dotted line whose time is
in the legend; a run without impacts marks its configuration switches.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import UsageError
from .trajectory import Trajectory, atomic_write

WITH_IMPACT = "Considering impact motion"
WITHOUT_IMPACT = "Without considering impact motion"
_STYLE = {True: dict(color="C3", lw=1.4, ls="-", zorder=3), False: dict(color="C0", lw=1.4, ls="--", zorder=2)}
_GREEK = {"alpha", "beta", "gamma", "delta", "theta", "phi", "psi", "omega", "tau", "lambda", "mu", "sigma"}
_DPI = 130


def _matplotlib():
    try:
        import matplotlib
    except ImportError:
        raise UsageError("figures need matplotlib, an optional extra: pip install 'pcmm[plots]'") from None
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    def make(**kw):  # the Agg canvas, without pyplot's global state
        fig = Figure(**kw)
        FigureCanvasAgg(fig)
        return fig
    return make


# ---- what the runs hold ------------------------------------------------------------------------
@dataclass
class _Run:
    traj: Trajectory
    label: str
    style: dict

    @property
    def t(self) -> np.ndarray:
        return self.traj.t


def _runs(traj: Trajectory, compare: Trajectory | None) -> list[_Run]:
    runs = [traj] + ([compare] if compare is not None else [])
    out = []
    for i, r in enumerate(runs):
        label = WITH_IMPACT if r.impact else WITHOUT_IMPACT
        if any(o.label == label for o in out):
            label += " (compared run)"
        out.append(_Run(r, label, dict(_STYLE[bool(r.impact)])))
        if i and out[0].style == out[-1].style:
            out[-1].style.update(color="C2", ls=":")
    # the run without impact first (underneath, first in the legend), as in the paper
    return sorted(out, key=lambda r: (bool(r.traj.impact), r is not out[0]))


def _range(a: np.ndarray) -> float:
    a = a[np.isfinite(a)]
    return float(np.ptp(a)) if a.size else 0.0


def _rotating_links(traj: Trajectory) -> list[str]:
    return [link for link in traj.links
            if _range(traj.series("theta", link)) > 1e-9 or np.nanmax(np.abs(traj.series("omega", link))) > 1e-12]


def _translating_links(traj: Trajectory) -> list[str]:
    out = []
    for link in traj.links:
        xy = traj.series("xy", link)
        if _range(traj.series("theta", link)) <= 1e-9 and max(_range(xy[:, 0]), _range(xy[:, 1])) > 1e-9:
            out.append(link)
    return out


def _scene(traj: Trajectory):
    """The run's scene if its file is reachable (units and prismatic joints), else None."""
    try:
        from .scene import load_scene
        return load_scene(traj.scene) if Path(traj.scene).is_file() else None
    except Exception:  # the figures do not depend on it
        return None


def _joint_types(scene) -> dict[str, str]:
    out = {}
    if scene is not None:
        for cfg in scene.configurations.values():
            for name, j in cfg.info.joints.items():
                out.setdefault(name, j.type)
    return out


def _coordinates(traj: Trajectory) -> list[str]:
    return list(dict.fromkeys(c for s in traj.segments for c in s.coordinates))


def _names(traj: Trajectory, field: str) -> list[str]:
    return list(dict.fromkeys(n for s in traj.segments for n in getattr(s, field)))


def _impact_marks(runs: list[_Run], duration: float) -> tuple[list[float], str]:
    """Times to mark: the first impact of each burst (or configuration switches)."""
    impact_runs = [r for r in runs if r.traj.impact]
    for r in impact_runs + runs:
        evs = [e for e in r.traj.events if e.get("impact")] if r.traj.impact else \
              [e for e in r.traj.events if e.get("from") != e.get("to")]
        if evs:
            kind = "impact" if r.traj.impact else "configuration switch"
            gap = 0.01 * duration
            marks, last = [], -math.inf
            for e in evs:
                if e["t"] - last > gap:
                    marks.append(float(e["t"]))
                last = e["t"]
            return marks[:6], kind
    return [], ""


def _bursts(traj: Trajectory, duration: float) -> list[tuple[float, float, int]]:
    """(first, last, count) of each burst of impacts (events closer than 1% of the run)."""
    out: list[list] = []
    for e in traj.events:
        if not e.get("impact"):
            continue
        if out and e["t"] - out[-1][1] <= 0.01 * duration:
            out[-1][1] = e["t"]
            out[-1][2] += 1
        else:
            out.append([e["t"], e["t"], 1])
    return [tuple(b) for b in out]


# ---- labels -----------------------------------------------------------------------------------
def _sym(base: str, name: str) -> str:
    """``_sym("theta", "link3") -> $\\theta_{3}$``; ``_sym("tau", "tau1") -> $\\tau_{1}$``."""
    m = re.fullmatch(r"([A-Za-z]+)_?(\d+)", name)
    if m and m.group(1).lower() in _GREEK:
        return rf"$\{m.group(1).lower()}_{{{m.group(2)}}}$"
    if m:
        return rf"${base}_{{{m.group(2)}}}$"
    safe = re.sub(r"([_{}$#%&^])", r"\\\1", name)
    return rf"${base}_{{\mathrm{{{safe}}}}}$"


def _fmt_t(t: float) -> str:
    return f"t = {t:.4f} s"


# ---- drawing ----------------------------------------------------------------------------------
class _Figure:
    def __init__(self, Figure, n: int, title: str, ncols: int | None = None):
        self.ncols = ncols or (1 if n == 1 else 2)
        self.nrows = math.ceil(n / self.ncols)
        self.fig = Figure(figsize=(6.4 * self.ncols, 3.9 * self.nrows), dpi=_DPI, layout="constrained")
        self.axes = list(np.atleast_1d(self.fig.subplots(self.nrows, self.ncols)).flat)
        for ax in self.axes[n:]:
            ax.set_visible(False)
        self.axes = self.axes[:n]
        self.fig.suptitle(title, fontsize=11)

    def legend(self, ax=None, handles=None):
        """One legend for the whole figure, below the panels."""
        ax = ax or self.axes[0]
        if handles is None:
            handles, labels = ax.get_legend_handles_labels()
        else:
            labels = [h.get_label() for h in handles]
        if handles:
            room = 110 * self.ncols  # characters that fit on one legend row
            ncol = max(1, min(len(handles), room // (max(len(lab) for lab in labels) + 8)))
            self.fig.legend(handles, labels, loc="outside lower center", ncol=ncol, fontsize=9, frameon=False)

    def save(self, path: Path) -> Path:
        return atomic_write(path, lambda f: self.fig.savefig(f, format="png", dpi=_DPI), force=True, binary=True)


def _panel(ax, runs, get, ylabel, title, marks, kind, duration):
    for r in runs:
        y = get(r)
        if y is None:
            continue
        ax.plot(r.t, y, label=r.label, **r.style)
    _mark(ax, marks, kind)
    ax.set_xlabel("t (s)")
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    ax.set_xlim(0.0, duration)
    ax.grid(True, alpha=0.3)


def _mark(ax, marks, kind):
    for i, t in enumerate(marks):
        ax.axvline(t, color="0.35", ls=":", lw=1.2, zorder=1,
                   label=f"{kind}, {_fmt_t(t)}" if i < 3 else None)


def _inset(ax, runs, get, window, marks):
    """A zoom on ``window`` = (t0, t1) in the lower right of ``ax``."""
    t0, t1 = window
    ys = []
    ins = ax.inset_axes([0.56, 0.08, 0.4, 0.36])
    for r in runs:
        y = get(r)
        if y is None:
            continue
        sel = (r.t >= t0) & (r.t <= t1)
        if sel.any():
            ins.plot(r.t[sel], y[sel], **{**r.style, "lw": 1.0})
            ys.append(y[sel][np.isfinite(y[sel])])
    for t in marks:
        if t0 <= t <= t1:
            ins.axvline(t, color="0.35", ls=":", lw=1.0)
    ys = np.concatenate(ys) if ys else np.zeros(0)
    if ys.size:
        lo, hi = float(ys.min()), float(ys.max())
        pad = 0.1 * (hi - lo) or 1e-6 * max(1.0, abs(hi))
        ins.set_ylim(lo - pad, hi + pad)
    ins.set_xlim(t0, t1)
    ins.tick_params(labelsize=7)
    ins.grid(True, alpha=0.3)
    ax.indicate_inset_zoom(ins, edgecolor="0.3")
    return ins


def _zoom_window(runs, duration):
    for r in runs:
        if r.traj.impact:
            b = _bursts(r.traj, duration)
            if b:
                t0, t1, _ = b[0]
                return max(0.0, t0 - 0.03 * duration), min(duration, t1 + 0.05 * duration)
    return None


# ---- the figures ---------------------------------------------------------------------------------
def write_figures(traj: Trajectory, out_dir: str | Path, compare: Trajectory | None = None) -> list[Path]:
    """Write the figures the data support into ``out_dir`` (created if needed); return their paths."""
    Figure = _matplotlib()
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise UsageError(f"{out_dir}: not a folder")
    out_dir.mkdir(parents=True, exist_ok=True)
    if not traj.segments:
        raise UsageError("the trajectory is empty: nothing to plot")
    runs = _runs(traj, compare)
    duration = max(float(np.nanmax(r.t)) for r in runs if r.t.size)
    marks, kind = _impact_marks(runs, duration)
    scene = _scene(traj)
    jtypes = _joint_types(scene)
    files: list[Path] = []
    name = traj.scene_name
    letters = "abcdefghijklmnopqrstuvwxyz"

    def series(quantity, key=None):
        def get(r):
            names = {"theta": "links", "omega": "links", "forces": "force_names",
                     "constraint_forces": "constraint_labels"}.get(quantity)
            if names and key not in _names(r.traj, names):
                return None
            return r.traj.series(quantity, key)
        return get

    # Fig. 6 (a-c): absolute angles; Fig. 7: angular velocities
    rotating = _rotating_links(traj)
    if rotating:
        for fname, quantity, base, unit, what in (
                ("link_angles.png", "theta", r"\theta", "rad", "Angle of"),
                ("angular_velocities.png", "omega", r"\omega", "rad/s", "Angular velocity of")):
            f = _Figure(Figure, len(rotating), f"{name}: {what.lower()} the links")
            for i, (ax, link) in enumerate(zip(f.axes, rotating)):
                _panel(ax, runs, series(quantity, link), f"{_sym(base, link)} ({unit})",
                       f"({letters[i % 26]}) {what} {link}", marks, kind, duration)
            f.legend()
            files.append(f.save(out_dir / fname))
    # Fig. 6 (d): relative angles between consecutive rotating links
    pairs = list(zip(rotating, rotating[1:]))
    if pairs:
        f = _Figure(Figure, len(pairs), f"{name}: relative angles")
        for i, (ax, (a, b)) in enumerate(zip(f.axes, pairs)):
            def rel(r, a=a, b=b):
                if a not in r.traj.links or b not in r.traj.links:
                    return None
                return r.traj.series("theta", b) - r.traj.series("theta", a)
            ylabel = _sym(r"\theta", b) + " $-$ " + _sym(r"\theta", a) + " (rad)"
            _panel(ax, runs, rel, ylabel,
                   f"({letters[i % 26]}) Angle of {b} relative to {a}", marks, kind, duration)
        f.legend()
        files.append(f.save(out_dir / "relative_angles.png"))
    # Fig. 8: force element outputs
    forces = _names(traj, "force_names")
    if forces:
        specs = {fs.name: fs for fs in scene.forces} if scene is not None else {}
        f = _Figure(Figure, len(forces), f"{name}: force elements (joint moments)")
        for i, (ax, fn) in enumerate(zip(f.axes, forces)):
            spec = specs.get(fn)
            if spec is None:
                unit = "N·m or N"
            else:
                unit = "N" if spec.on.kind == "joint" and jtypes.get(spec.on.name) == "prismatic" else "N·m"
            where = f" on {spec.on.name}" if spec is not None else ""
            _panel(ax, runs, series("forces", fn), f"{_sym('f', fn)} ({unit})",
                   f"({letters[i % 26]}) {fn}{where}", marks, kind, duration)
        f.legend()
        files.append(f.save(out_dir / "force_elements.png"))
    # Figs. 9 / 15: energy (kinetic left axis, potential right axis)
    f = _Figure(Figure, 1, f"{name}: energy of the system")
    ax = f.axes[0]
    ax2 = ax.twinx()
    handles = []
    for r in runs:
        tag = "" if len(runs) == 1 else f" ({r.label[0].lower()}{r.label[1:]})"
        handles += ax.plot(r.t, r.traj.series("kinetic"), label=f"Kinetic energy{tag}",
                           **{**r.style, "color": "C0" if r.traj.impact else "C9"})
        handles += ax2.plot(r.t, r.traj.series("potential"), label=f"Potential energy{tag}",
                            **{**r.style, "color": "C3" if r.traj.impact else "C1"})
    _mark(ax, marks, kind)
    handles += [h for h in ax.get_lines() if h.get_label().startswith(kind)] if marks else []
    ax.set_xlabel("t (s)")
    ax.set_ylabel("Kinetic energy (J)")
    ax2.set_ylabel("Potential energy (J)")
    ax.set_xlim(0.0, duration)
    ax.grid(True, alpha=0.3)
    f.legend(handles=handles)
    files.append(f.save(out_dir / "energy.png"))
    # Fig. 12: impulse per impact
    impact_runs = [r for r in runs if r.traj.impact]
    evs = [(float(e["t"]), float(e["impulse"]["normal"])) for r in impact_runs[:1] for e in r.traj.events
           if e.get("impact") and e.get("impulse") is not None]
    if evs:
        t_ev, p_ev = np.array(evs).T
        f = _Figure(Figure, 1, f"{name}: impulse of each impact ({len(evs)} impact{'s' if len(evs) > 1 else ''})")
        ax = f.axes[0]
        ax.stem(t_ev, p_ev, linefmt="C3-", markerfmt="C3o", basefmt="0.5")
        ax.set_xlabel("t (s)")
        ax.set_ylabel(r"$P_n$ (N·s)")
        ax.margins(y=0.15)
        ax.set_xlim(0.0, duration)
        ax.grid(True, alpha=0.3)
        if p_ev.size:
            ax.annotate(_fmt_t(t_ev[0]), (t_ev[0], p_ev[0]), textcoords="offset points", xytext=(8, 6),
                        fontsize=8)
        bursts = _bursts(impact_runs[0].traj, duration)
        if bursts and bursts[0][2] > 3:  # a macro-impact: zoom on its micro-impacts
            t0, t1, _ = bursts[0]
            w = max(t1 - t0, 1e-6)
            ins = ax.inset_axes([0.56, 0.5, 0.4, 0.4])
            sel = (t_ev >= t0 - 0.1 * w) & (t_ev <= t1 + 0.1 * w)
            ins.stem(t_ev[sel], p_ev[sel], linefmt="C3-", markerfmt="C3.", basefmt="0.5")
            ins.set_xlim(t0 - 0.1 * w, t1 + 0.1 * w)
            ins.tick_params(labelsize=7)
            ins.set_title(f"first burst: {bursts[0][2]} impacts", fontsize=7)
        files.append(f.save(out_dir / "impulses.png"))
    # Fig. 13: slider position and velocity, inset zoom around the first impact
    sliders = _sliders(traj, scene, jtypes)
    if sliders:
        window = _zoom_window(runs, duration)
        f = _Figure(Figure, 2 * len(sliders), f"{name}: slider", ncols=2)
        for i, s in enumerate(sliders):
            for j, (get, ylabel, what) in enumerate(((s.position, f"{s.symbol} (m)", "Position"),
                                                     (s.velocity, f"{s.symbol}$'$ (m/s)", "Velocity"))):
                ax = f.axes[2 * i + j]
                _panel(ax, runs, get, ylabel, f"({letters[(2 * i + j) % 26]}) {what} of {s.name}",
                       marks, kind, duration)
                if window:
                    _inset(ax, runs, get, window, marks)
        f.legend()
        files.append(f.save(out_dir / "slider.png"))
    # Fig. 14: driving moments
    drives = [lab for lab in _names(traj, "constraint_labels") if lab.endswith(".drive")]
    if drives:
        window = _zoom_window(runs, duration)
        f = _Figure(Figure, len(drives), f"{name}: driving moment")
        for i, (ax, lab) in enumerate(zip(f.axes, drives)):
            joint = lab[: -len(".drive")]
            unit = "N" if jtypes.get(joint) == "prismatic" else "N·m"
            get = series("constraint_forces", lab)
            _panel(ax, runs, get, f"M ({unit})", f"({letters[i % 26]}) Driving {'force' if unit == 'N' else 'moment'}"
                   f" at {joint}", marks, kind, duration)
            if window:
                _inset(ax, runs, get, window, marks)
        f.legend()
        files.append(f.save(out_dir / "driving_moment.png"))
    return files


@dataclass
class _Slider:
    name: str
    symbol: str
    position: object  # _Run -> array | None
    velocity: object


def _sliders(traj: Trajectory, scene, jtypes) -> list[_Slider]:
    out: list[_Slider] = []
    covered = set()
    for link in _translating_links(traj):
        xy = traj.series("xy", link)
        ok = np.isfinite(xy[:, 0])
        centered = xy[ok] - xy[ok].mean(axis=0)
        d = np.linalg.svd(centered, full_matrices=False)[2][0]  # line of motion
        d = d if d[np.argmax(np.abs(d))] > 0 else -d
        symbol = "$x$" if abs(d[0]) > 0.999 else "$y$" if abs(d[1]) > 0.999 else "$s$"

        def pos(r, link=link, d=d):
            if link not in r.traj.links:
                return None
            return r.traj.series("xy", link) @ d

        def vel(r, link=link, d=d):
            if link not in r.traj.links:
                return None
            parts = []
            for s in r.traj.segments:
                if link not in s.links or len(s.t) < 2 or s.t[-1] <= s.t[0]:
                    parts.append(np.full(len(s.t), np.nan))
                    continue
                x = s.xy[:, s.links.index(link)] @ d
                t, keep = np.unique(s.t, return_index=True)
                v = np.gradient(x[keep], t, edge_order=2 if len(t) > 2 else 1)
                parts.append(np.interp(s.t, t, v))
            return np.concatenate(parts)
        out.append(_Slider(link, symbol, pos, vel))
        covered.add(link)
    if scene is not None:  # prismatic coordinates whose link is not a plain slider (it also turns)
        children = {n: j.child for cfg in scene.configurations.values() for n, j in cfg.info.joints.items()}
        for c in _coordinates(traj):
            if jtypes.get(c) == "prismatic" and children.get(c) not in covered:
                out.append(_Slider(c, _sym("q", c), lambda r, c=c: r.traj.series("q", c),
                                   lambda r, c=c: r.traj.series("v", c)))
    return out


__all__ = ["write_figures", "WITH_IMPACT", "WITHOUT_IMPACT"]
