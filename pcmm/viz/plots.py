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
``impulses.png``               impulse per impact (stem plot): P_n, and    Fig. 12
                               P_t and abs P where it is two-dimensional
``slider.png``                 slider position and velocity, inset zoom    Fig. 13
                               around the first impact
``driving_moment.png``         driving moment (constraint rows "*.drive")  Fig. 14
``holding_forces.png``         holding force or moment of every lock       (sizing a latch)
                               (constraint rows "*.hold")
=============================  ==========================================  ================

``impulses.png`` needs events with an impulse, ``slider.png`` a translating
link (a link whose angle never changes while its origin moves: position
along its line of motion; velocity by differentiating the recorded
positions within each segment) or prismatic coordinates, and
``driving_moment.png`` constraint forces labelled ``<joint>.drive``.

With ``compare`` (usually the run without impact) both runs are overlaid:
"Considering impact motion" (solid) and "Without considering impact motion"
(dashed), labelled by each run's ``impact`` flag.

Every event of the run (of the run with impact when two are overlaid) is
marked by a vertical line in its kind's style: impact (dotted grey), merge
(dash-dot purple), release (dashed green), configuration switch without
impact (dotted black).  A burst of more than three impacts closer than 1 % of
the run (a macro-impact) is one shaded span with one legend entry ("35
impacts, t = a ... b s"); a kind with more than three marks gets one legend
entry that counts them.

``impulses.png`` states its sign convention on the figure: by default ``P_n``
is the impulse on body b along the contact normal n (from a to b), as the
event records it; ``impulse_sign="paper"`` plots the paper's sign (its Fig. 12,
negative for a slider stopped by the frame).  ``energy.png`` annotates the run
without impact: its switches are velocity resets, not impacts, and can change
the kinetic energy either way; the annotation gives that change at each switch.

Nothing here reads the scene: units (N or N·m) and prismatic coordinates come
from what the trajectory recorded (:attr:`Trajectory.views`).  :func:`figures`
returns the matplotlib figures (``Trajectory.plot``); :func:`write_figures`
saves them as PNG.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import UsageError
from ..files import atomic_write
from .marks import RecordedRun, event_kind
from .canvas import _matplotlib

WITH_IMPACT = "Considering impact motion"
WITHOUT_IMPACT = "Without considering impact motion"
_STYLE = {True: dict(color="C3", lw=1.4, ls="-", zorder=3), False: dict(color="C0", lw=1.4, ls="--", zorder=2)}
_GREEK = {"alpha", "beta", "gamma", "delta", "theta", "phi", "psi", "omega", "tau", "lambda", "mu", "sigma"}
_DPI = 130


# ---- what the runs hold ------------------------------------------------------------------------
@dataclass
class _Run:
    traj: RecordedRun
    label: str
    style: dict

    @property
    def t(self) -> np.ndarray:
        return self.traj.t


def _runs(traj: RecordedRun, compare: RecordedRun | None) -> list[_Run]:
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


def angle_differences(a: RecordedRun, b: RecordedRun) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """``{link: (t, theta_a(t) - theta_b(t))}`` at ``a``'s samples (``b`` linear between its
    own), for the links that turn in either run."""
    out = {}
    tb = b.t
    for link in a.links:
        if link not in b.links or (link not in _rotating_links(a) and link not in _rotating_links(b)):
            continue
        ya, yb = a.series("theta", link), b.series("theta", link)
        ok = np.isfinite(yb)
        if not ok.any():
            continue
        out[link] = (a.t, ya - np.interp(a.t, tb[ok], yb[ok]))
    return out


def _range(a: np.ndarray) -> float:
    a = a[np.isfinite(a)]
    return float(np.ptp(a)) if a.size else 0.0


def _rotating_links(traj: RecordedRun) -> list[str]:
    return [link for link in traj.links
            if _range(traj.series("theta", link)) > 1e-9 or np.nanmax(np.abs(traj.series("omega", link))) > 1e-12]


def _translating_links(traj: RecordedRun) -> list[str]:
    out = []
    for link in traj.links:
        xy = traj.series("xy", link)
        if _range(traj.series("theta", link)) <= 1e-9 and max(_range(xy[:, 0]), _range(xy[:, 1])) > 1e-9:
            out.append(link)
    return out


def _joints(traj: RecordedRun) -> dict[str, dict]:
    """``{joint: {"type", "parent", "child"}}`` over the configurations the trajectory recorded."""
    out: dict[str, dict] = {}
    for view in traj.views.get("configurations", {}).values():
        for name, j in view.get("joints", {}).items():
            out.setdefault(name, j)
    return out


def _joint_types(traj: RecordedRun) -> dict[str, str]:
    return {n: j["type"] for n, j in _joints(traj).items()}


def _coordinates(traj: RecordedRun) -> list[str]:
    return list(dict.fromkeys(c for s in traj.segments for c in s.coordinates))


def _names(traj: RecordedRun, field: str) -> list[str]:
    return list(dict.fromkeys(n for s in traj.segments for n in getattr(s, field)))


@dataclass(frozen=True)
class _Mark:
    """One marked event, or a burst of impacts (``count`` > 1, from ``t0`` to ``t1``)."""

    kind: str  # "impact" | "merge" | "release" | "switch"
    t0: float
    t1: float
    count: int = 1


_MARK_STYLE = {"impact": dict(color="0.35", ls=":"), "merge": dict(color="#7b3fb5", ls="-."),
               "release": dict(color="#1a9a3a", ls="--"), "switch": dict(color="0.1", ls=":")}
_MARK_NAME = {"impact": "impact", "merge": "merge", "release": "release", "switch": "configuration switch"}


def _event_marks(runs: list[_Run], duration: float) -> list[_Mark]:
    """Every event of the (first) run with impact, else of the first run.  Impacts closer than
    1 % of the run form a burst; a burst of more than three is one mark (plus its merge)."""
    run = next((r for r in runs if r.traj.impact), runs[0])
    marks: list[_Mark] = []
    burst: list[tuple[float, str]] = []

    def flush():
        if len(burst) > 3:
            marks.append(_Mark("impact", burst[0][0], burst[-1][0], len(burst)))
            marks.extend(_Mark(k, t, t) for t, k in burst if k == "merge")
        else:
            marks.extend(_Mark(k, t, t) for t, k in burst)
        burst.clear()
    for e in run.traj.events:
        t, kind = float(e["t"]), event_kind(e)
        if e.get("impact"):
            if burst and t - burst[-1][0] > 0.01 * duration:
                flush()
            burst.append((t, kind))
        else:
            flush()
            marks.append(_Mark(kind, t, t))
    flush()
    return marks


def _mark_labels(marks: list[_Mark]) -> dict[int, str]:
    """Legend text per mark index: each mark while a kind has at most three, else one counting entry."""
    out = {}
    for kind in _MARK_NAME:
        idx = [i for i, m in enumerate(marks) if m.kind == kind]
        if len(idx) <= 3:
            for i in idx:
                m = marks[i]
                out[i] = (f"{m.count} {_MARK_NAME[kind]}s, t = {m.t0:.4f} ... {m.t1:.4f} s" if m.count > 1
                          else f"{_MARK_NAME[kind]}, {_fmt_t(m.t0)}")
        else:
            n = sum(marks[i].count for i in idx)
            out[idx[0]] = f"{n} {_MARK_NAME[kind]}s, t = {marks[idx[0]].t0:.4f} ... {marks[idx[-1]].t1:.4f} s"
    return out


def _bursts(traj: RecordedRun, duration: float) -> list[tuple[float, float, int]]:
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
    if re.fullmatch(r"[A-Za-z0-9 .\-_]+", name):
        safe = name.replace("_", "\\_")
        return rf"${base}_{{\mathrm{{{safe}}}}}$"
    return rf"${base}$ [{_plain(name)}]"  # any other name stays plain text: mathtext never parses it


def _plain(text: str) -> str:
    """Text shown as it is: a ``$`` in a name would start mathtext (and ``$\\x$`` crash it)."""
    return text.replace("$", r"\$")


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
        self.fig.suptitle(_plain(title), fontsize=11)

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


def _panel(ax, runs, get, ylabel, title, marks, duration):
    for r in runs:
        y = get(r)
        if y is None:
            continue
        ax.plot(r.t, y, label=r.label, **r.style)
    _mark(ax, marks)
    ax.set_xlabel("t (s)")
    ax.set_ylabel(ylabel)
    ax.set_title(_plain(title), fontsize=10)
    ax.set_xlim(0.0, duration)
    ax.grid(True, alpha=0.3)


def _mark(ax, marks: list[_Mark]):
    """Draw every mark; return the legend handles (one per legend entry)."""
    labels = _mark_labels(marks)
    handles = []
    for i, m in enumerate(marks):
        line = ax.axvline(m.t0, lw=1.2, zorder=1, label=labels.get(i, "_nolegend_"), **_MARK_STYLE[m.kind])
        if m.count > 1:
            ax.axvspan(m.t0, m.t1, color=_MARK_STYLE[m.kind]["color"], alpha=0.18, lw=0, zorder=0)
            ax.axvline(m.t1, lw=1.2, zorder=1, **_MARK_STYLE[m.kind])
        if i in labels:
            handles.append(line)
    return handles


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
    for m in marks:
        for t in {m.t0, m.t1}:
            if t0 <= t <= t1:
                ins.axvline(t, lw=1.0, **_MARK_STYLE[m.kind])
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
IMPULSE_SIGNS = {
    "body_b": (1.0, r"$P_n > 0$: the impulse on body b along the contact normal n (from a to b), as the "
                    "events record it; the paper's Fig. 12 plots the opposite sign (impulse_sign='paper')"),
    "paper": (-1.0, r"the paper's sign (its Fig. 12): $-P_n$, the impulse on body a (the stop, for a slider "
                    "stopped by the frame) along n; pcmm's events record $P_n$ on body b"),
}


def write_figures(traj: RecordedRun, out_dir: str | Path, compare: RecordedRun | None = None,
                  impulse_sign: str = "body_b") -> list[Path]:
    """Write the figures the data support into ``out_dir`` (created if needed); return their paths."""
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise UsageError(f"{out_dir}: not a folder")
    figs = figures(traj, compare=compare, impulse_sign=impulse_sign)
    out_dir.mkdir(parents=True, exist_ok=True)
    return [atomic_write(out_dir / f"{stem}.png", lambda f, fig=fig: fig.savefig(f, format="png", dpi=_DPI),
                        force=True, binary=True) for stem, fig in figs.items()]


def figures(traj: RecordedRun, compare: RecordedRun | None = None, impulse_sign: str = "body_b") -> dict:
    """The figures the data support, ``{file stem: matplotlib Figure}`` (no pyplot state)."""
    Figure = _matplotlib()
    if impulse_sign not in IMPULSE_SIGNS:
        raise UsageError(f"impulse_sign = {impulse_sign!r}: must be one of {', '.join(IMPULSE_SIGNS)}")
    if not traj.segments:
        raise UsageError("the trajectory is empty: nothing to plot")
    runs = _runs(traj, compare)
    duration = max(float(np.nanmax(r.t)) for r in runs if r.t.size)
    marks = _event_marks(runs, duration)
    jtypes = _joint_types(traj)
    files: dict = {}
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
                       f"({letters[i % 26]}) {what} {link}", marks, duration)
            f.legend()
            files[fname[:-4]] = f.fig
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
                   f"({letters[i % 26]}) Angle of {b} relative to {a}", marks, duration)
        f.legend()
        files["relative_angles"] = f.fig
    # with a comparison run: the difference of the link angles, visible where the curves lie on each other
    if compare is not None and len(runs) == 2:
        diffs = angle_differences(runs[-1].traj, runs[0].traj)
        if diffs:
            f = _Figure(Figure, len(diffs), f"{name}: link angles, {runs[-1].label} − {runs[0].label}")
            for i, (ax, (link, (t, d))) in enumerate(zip(f.axes, diffs.items())):
                ax.plot(t, d, color="C4", lw=1.3, label=f"{runs[-1].label} − {runs[0].label}")
                _mark(ax, marks)
                ax.set_xlabel("t (s)")
                ax.set_ylabel("Δθ (rad)")
                ax.set_title(_plain(f"({letters[i % 26]}) Difference of {link}'s angle"), fontsize=10)
                ax.set_xlim(0.0, duration)
                ax.grid(True, alpha=0.3)
            f.legend()
            files["angle_differences"] = f.fig
    # Fig. 8: force element outputs
    forces = _names(traj, "force_names")
    if forces:
        specs = traj.views.get("forces", {})
        f = _Figure(Figure, len(forces), f"{name}: force elements (joint moments)")
        for i, (ax, fn) in enumerate(zip(f.axes, forces)):
            spec = specs.get(fn, {})
            on = spec.get("on")
            if spec.get("points"):  # a point spring: a force along its line
                unit, where = "N", f" between {spec['points'][0]} and {spec['points'][1]}"
            elif on is None:
                unit, where = "N·m or N", ""
            else:
                unit = "N" if on["kind"] == "joint" and jtypes.get(on["name"]) == "prismatic" else "N·m"
                where = f" on {on['name']}"
            _panel(ax, runs, series("forces", fn), f"{_sym('f', fn)} ({unit})",
                   f"({letters[i % 26]}) {fn}{where}", marks, duration)
        f.legend()
        files["force_elements"] = f.fig
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
    handles += _mark(ax, marks)
    for r in runs:
        if not r.traj.impact:
            _annotate_switch_energy(ax, r)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("Kinetic energy (J)")
    ax2.set_ylabel("Potential energy (J)")
    ax.set_xlim(0.0, duration)
    ax.grid(True, alpha=0.3)
    f.legend(handles=handles)
    files["energy"] = f.fig
    # Fig. 12: impulse per impact, in the sign convention the figure states
    impact_runs = [r for r in runs if r.traj.impact]
    sign, convention = IMPULSE_SIGNS[impulse_sign]
    evs = [(float(e["t"]), sign * float(e["impulse"]["normal"]), sign * float(e["impulse"].get("tangential") or 0.0))
           for r in impact_runs[:1] for e in r.traj.events if e.get("impact") and e.get("impulse") is not None]
    if evs:
        t_ev, p_ev, pt_ev = np.array(evs).T
        f = _Figure(Figure, 1, f"{name}: impulse of each impact ({len(evs)} impact{'s' if len(evs) > 1 else ''})")
        ax = f.axes[0]
        stems = ax.stem(t_ev, p_ev, linefmt="C3-", markerfmt="C3o", basefmt="0.5")
        handles = _mark(ax, marks)
        two_d = bool(np.any(pt_ev != 0.0))  # a pin's or a frictional contact's impulse has a tangential part
        if two_d:  # P_t beside P_n, and |P| (the impulse is two-dimensional: P_n alone hides part of it)
            stems.markerline.set_label(r"$P_n$" if sign > 0 else r"$-P_n$")
            tang = ax.stem(t_ev, pt_ev, linefmt="C0--", markerfmt="C0s", basefmt="0.5")
            tang.markerline.set_label(r"$P_t$, along t = ($n_y$, $-n_x$)" if sign > 0 else r"$-P_t$")
            size, = ax.plot(t_ev, np.hypot(p_ev, pt_ev), "kx", ms=7, label=r"$|P|$")
            handles = [stems.markerline, tang.markerline, size] + list(handles)
        ax.set_xlabel("t (s)")
        ax.set_ylabel(("impulse (N·s)" if two_d else r"$P_n$ (N·s)") if sign > 0 else
                      (r"impulse on a (N·s), the paper's sign" if two_d else r"$-P_n$ (N·s), the paper's sign"))
        ax.margins(y=0.15)
        ax.set_xlim(0.0, duration)
        ax.grid(True, alpha=0.3)
        ax.set_title(convention, fontsize=8, wrap=True)
        if p_ev.size:
            # left of the first impact, unless that is in the axes' left third (the label would run
            # over the y axis): then right of it
            right = duration > 0 and t_ev[0] < duration / 3
            text = (f"{_fmt_t(t_ev[0])}, {p_ev[0]:.4g} N·s" if not two_d else
                    f"{_fmt_t(t_ev[0])}, P_n {p_ev[0]:.4g}, P_t {pt_ev[0]:.4g}, |P| {math.hypot(p_ev[0], pt_ev[0]):.4g} N·s")
            ax.annotate(text, (t_ev[0], p_ev[0]), textcoords="offset points",
                        xytext=(8 if right else -8, 6 if p_ev[0] >= 0 else -12), ha="left" if right else "right",
                        fontsize=8)
        bursts = _bursts(impact_runs[0].traj, duration)
        if bursts and bursts[0][2] > 3:  # a macro-impact: zoom on its micro-impacts
            t0, t1, _ = bursts[0]
            w = max(t1 - t0, 1e-6)
            up = float(np.sum(p_ev)) >= 0  # the inset where the stems are not
            ins = ax.inset_axes([0.56, 0.5 if up else 0.08, 0.4, 0.4])
            sel = (t_ev >= t0 - 0.1 * w) & (t_ev <= t1 + 0.1 * w)
            ins.stem(t_ev[sel], p_ev[sel], linefmt="C3-", markerfmt="C3.", basefmt="0.5")
            ins.set_xlim(t0 - 0.1 * w, t1 + 0.1 * w)
            ins.tick_params(labelsize=7)
            ins.set_title(f"first burst: {bursts[0][2]} impacts", fontsize=7)
        f.legend(handles=handles)
        files["impulses"] = f.fig
    # Fig. 13: slider position and velocity, inset zoom around the first impact
    sliders = _sliders(traj, jtypes)
    if sliders:
        window = _zoom_window(runs, duration)
        f = _Figure(Figure, 2 * len(sliders), f"{name}: slider", ncols=2)
        for i, s in enumerate(sliders):
            for j, (get, ylabel, what) in enumerate(((s.position, f"{s.symbol} (m)", "Position"),
                                                     (s.velocity, f"{s.symbol}$'$ (m/s)", "Velocity"))):
                ax = f.axes[2 * i + j]
                _panel(ax, runs, get, ylabel, f"({letters[(2 * i + j) % 26]}) {what} of {s.name}",
                       marks, duration)
                if window:
                    _inset(ax, runs, get, window, marks)
        f.legend()
        files["slider"] = f.fig
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
                   f" at {joint}", marks, duration)
            if window:
                _inset(ax, runs, get, window, marks)
        f.legend()
        files["driving_moment"] = f.fig
    # what each lock (latch, stop-merge) holds, over the time it holds: what a latch is sized by
    holds = [lab for lab in _names(traj, "constraint_labels") if lab.endswith(".hold")]
    if holds:
        f = _Figure(Figure, len(holds), f"{name}: holding forces of the locks")
        for i, (ax, lab) in enumerate(zip(f.axes, holds)):
            what = lab[: -len(".hold")]
            unit = {"revolute": "N·m", "prismatic": "N"}.get(jtypes.get(what), "N; N·m at a joint stop")
            kind = "moment" if unit == "N·m" else "force"
            note = "" if what in jtypes else " (the stop's normal force, > 0 compressive)"
            _panel(ax, runs, series("constraint_forces", lab), f"{kind} ({unit})",
                   f"({letters[i % 26]}) Holding {kind} of {what}{note}", marks, duration)
        f.legend()
        files["holding_forces"] = f.fig
    if traj.views.get("transitions"):  # the working cycle as a graph, with this run's firings
        from .graph import graph_figure
        files["graph"] = graph_figure(traj.views, traj.events, title=name).figure
    return files


def switch_energy_changes(traj: RecordedRun) -> list[tuple[float, float]]:
    """``[(t, KE+ - KE-)]`` at each merge or switch without impulse (releases are not velocity resets)."""
    return [(float(e["t"]), float(e["kinetic_energy_after"]) - float(e["kinetic_energy_before"]))
            for e in traj.events if not e.get("impact") and "kinetic_energy_after" in e
            and event_kind(e) in ("merge", "switch")]


def _annotate_switch_energy(ax, run: _Run) -> None:
    """State on the energy figure what the run without impact does to the kinetic energy at its
    switches: they are velocity resets (the locked joints' velocities dropped), not impacts, so
    no conservation law bounds them and the energy can rise."""
    changes = switch_energy_changes(run.traj)
    if not changes:
        return
    shown = changes[:2]
    lines = [f"{'+' if d >= 0 else '−'}{abs(d):.4g} J at t = {t:.4f} s" for t, d in shown]
    if len(changes) > 2:
        lines.append(f"... {len(changes)} switches, {sum(d for _, d in changes):+.4g} J in all")
    ax.set_title("Without impact (dashed), a switch keeps the surviving joints' velocities and drops the locked "
                 "joints' (no impulse, no conservation law): kinetic energy change " + "; ".join(lines),
                 fontsize=8, wrap=True)
    for t, d in shown:
        ke = run.traj.series("kinetic")
        k = int(np.searchsorted(run.t, t, side="right"))
        if 0 < k <= len(ke):
            ax.annotate(f"{d:+.3g} J", (t, ke[min(k, len(ke) - 1)]), textcoords="offset points", xytext=(6, 10),
                        fontsize=7.5, color="C9", arrowprops=dict(arrowstyle="->", color="C9", lw=0.8))


@dataclass
class _Slider:
    name: str
    symbol: str
    position: object  # _Run -> array | None
    velocity: object


def _sliders(traj: RecordedRun, jtypes) -> list[_Slider]:
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
    if jtypes:  # prismatic coordinates whose link is not a plain slider (it also turns)
        children = {n: j["child"] for n, j in _joints(traj).items()}
        for c in _coordinates(traj):
            if jtypes.get(c) == "prismatic" and children.get(c) not in covered:
                out.append(_Slider(c, _sym("q", c), lambda r, c=c: _coordinate_series(r, "q", c),
                                   lambda r, c=c: _coordinate_series(r, "v", c)))
    return out


def _coordinate_series(run, quantity: str, c: str):
    """A coordinate's series in ``run``, or None where that run has no such coordinate (a compared run)."""
    return run.traj.series(quantity, c) if c in _coordinates(run.traj) else None


__all__ = ["write_figures", "figures", "event_kind", "switch_energy_changes", "IMPULSE_SIGNS", "WITH_IMPACT",
           "WITHOUT_IMPACT"]
