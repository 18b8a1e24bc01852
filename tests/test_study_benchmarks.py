"""The throughput benchmark's steady-state rate (issue 25: a 168 % parallel efficiency for
Example 2 was a measurement artefact)."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _bench():
    spec = importlib.util.spec_from_file_location("bench_sweep", ROOT / "benchmarks" / "sweep.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_steady_rate_counts_from_the_end_of_the_first_wave():
    steady_rate = _bench().steady_rate
    # 4 runs of 1 s on 2 workers started at 0: rows land in pairs at 1 s and 2 s - 2 runs/s
    # from the pair that ends at 2 s; counting from the first row read 3 runs / 1 s (150 %)
    landed = [1.0, 1.0005, 2.0, 2.0005]
    assert steady_rate(landed, 2) == pytest.approx(2.0, rel=1e-12)
    # one worker: 4 runs of 1 s land at 1, 2, 3, 4 s - 1 run/s
    assert steady_rate([1.0, 2.0, 3.0, 4.0], 1) == pytest.approx(1.0)
    # 6 runs of 1 s on 3 workers: 3 runs/s (the first-row formula gave 5 runs/s)
    assert steady_rate([1.0, 1.0, 1.0, 2.0, 2.0, 2.0], 3) == pytest.approx(3.0)
