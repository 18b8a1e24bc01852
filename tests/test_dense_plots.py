"""Figures true to the run between its steps: a saved run's angles drawn as cubic Hermite
curves through the recorded angles and angular velocities agree with the integrator's own dense
output (an independent route: the run's interpolant), where straight lines between steps do not;
and a fresh run's figures are drawn from the dense output by default."""
from __future__ import annotations

from pathlib import Path

import numpy as np

import pcmm
from pcmm.results.trajectory import Trajectory
from pcmm.viz.dense import PLOT_SAMPLES, hermite, plot_times

ROOT = Path(__file__).resolve().parents[1]


def test_a_saved_runs_curves_follow_the_dense_output_without_kinks(tmp_path):
    fresh = pcmm.simulate(pcmm.load_scene(ROOT / "examples" / "three_bar.toml"), pcmm.RunOptions(t_end=0.3))
    fresh.save(tmp_path / "run.npz")
    saved = Trajectory.load(tmp_path / "run.npz")
    drawn = hermite(saved)
    for s_fresh, s_saved, s_drawn in zip(fresh.segments, saved.segments, drawn.segments):
        t = s_drawn.t
        assert set(s_saved.t) <= set(t)  # every step is kept, the grid added between
        assert np.max(np.diff(t)) <= 0.3 / PLOT_SAMPLES + 1e-12 or len(t) == len(s_saved.t)
        truth = s_fresh.resampled(t).theta  # the integrator's dense output at the same times
        linear = np.column_stack([np.interp(t, s_saved.t, s_saved.theta[:, j]) for j in range(truth.shape[1])])
        err_h, err_l = np.abs(s_drawn.theta - truth).max(), np.abs(linear - truth).max()
        span = np.ptp(truth, axis=0).max() + 1e-3
        assert err_h < 1e-4 * span, (err_h, span)  # a tenth of a pixel of a 1000-pixel-high figure
        if err_l > 1e-3 * span:  # where the steps are long, straight lines are visibly off and Hermite is not
            assert err_h < 0.05 * err_l, (err_h, err_l)
        # no kink at a step: the slope just before and just after a step agree with omega there
        inner = [k for k, tk in enumerate(t) if tk in set(s_saved.t[1:-1])]
        for k in inner[:50]:
            left = (s_drawn.theta[k] - s_drawn.theta[k - 1]) / (t[k] - t[k - 1])
            right = (s_drawn.theta[k + 1] - s_drawn.theta[k]) / (t[k + 1] - t[k])
            j = list(s_saved.t).index(t[k])
            scale = np.abs(s_saved.omega[j]).max() + 1.0
            assert np.abs(left - right).max() < 0.05 * scale


def test_plot_times_keep_the_events_and_the_steps():
    traj = pcmm.simulate(pcmm.load_scene(ROOT / "examples" / "three_bar.toml"), pcmm.RunOptions(t_end=0.3))
    for s in traj.segments:
        times = plot_times(traj, s)
        assert times[0] == s.t[0] and times[-1] == s.t[-1]  # an event's instant is a sample
        assert set(s.t) <= set(times)
