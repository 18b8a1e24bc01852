"""A run streamed to a chunked store as it goes (issue 26, item 5): the same record as a run
kept in memory, bounded memory, and every chunk written before a kill readable."""
from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import builders
import numpy as np
import pytest

import pcmm
import pcmm.cli
from pcmm.errors import SimulationError, UsageError
from pcmm.results.store import StoreWriter, chunk_path
from pcmm.results.summary import summary

G = 9.81
PERIOD = 2.0 * math.sqrt(2.0 / G)  # a ball with e = 1 from h = 1 m: one bounce every 0.903 s
SERIES = ("q", "v", "theta", "omega", "xy", "kinetic", "potential", "forces", "constraint_forces")


def _same_record(a, b):
    assert len(a.segments) == len(b.segments) and len(a.events) == len(b.events)
    np.testing.assert_array_equal(a.t, b.t)
    for x, y in zip(a.segments, b.segments):
        assert x.configuration == y.configuration
        assert (x.coordinates, x.links, x.force_names, x.constraint_labels) == \
               (y.coordinates, y.links, y.force_names, y.constraint_labels)
        for name in SERIES:
            np.testing.assert_array_equal(getattr(x, name), getattr(y, name), err_msg=name)
    assert list(a.events) == list(b.events)


def _summary_text(traj):
    s = summary(traj)
    s["stats"] = {k: v for k, v in s["stats"].items() if k not in ("wall_s", "record_s")}
    return json.dumps(s, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o))


@pytest.mark.parametrize("scene_of", ["ball", "three_bar"])
def test_a_stored_run_is_the_run_kept_in_memory(tmp_path, scene_of):
    """Chunks of at most 5 segments or events, or 20 samples (Example 1 records 38, then 13): the stored run (as returned, and read back from its
    folder) has every array, event and summary value of the same run kept in memory.  The ball
    (e = 1) bounces 20 times by 19.5 periods; Example 1 latches (a loop, then a merge with its
    hold) before 0.3 s."""
    if scene_of == "ball":
        scene, t_end = pcmm.load_scene(builders.ball(tmp_path, 1.0, merge=False)), 19.5 * PERIOD
    else:
        scene, t_end = pcmm.load_scene("examples/three_bar.toml"), 0.3
    opts = pcmm.RunOptions(t_end=t_end)
    kept = pcmm.simulate(scene, opts)
    stored = pcmm.simulate(scene, opts, store=StoreWriter(tmp_path / "store", chunk_samples=20, chunk_records=5))
    back = pcmm.Trajectory.load(tmp_path / "store")
    chunks = sorted(p.name for p in (tmp_path / "store").glob("chunk-*.npz"))
    assert len(chunks) >= (4 if scene_of == "ball" else 2)
    if scene_of == "ball":
        assert len(kept.events) == 20
    for other in (stored, back):
        _same_record(kept, other)
        assert _summary_text(other) == _summary_text(kept)
    assert back.status == "complete" and back.source == str(tmp_path / "store")


KILLED = r"""
import sys, pcmm
from pcmm.results.store import StoreWriter
scene = pcmm.load_scene(sys.argv[1])
pcmm.simulate(scene, pcmm.RunOptions(t_end=1e6), store=StoreWriter(sys.argv[2], chunk_samples=10**9, chunk_records=4))
"""


def test_a_run_killed_midway_leaves_every_chunk_it_wrote_readable(tmp_path):
    """A run of a million seconds of bouncing is killed (SIGKILL: no handler runs) once it has
    written 3 chunks of 4 segments each; the store reads as a partial run with every chunk written
    before the kill, and its events and arrays are those of the same run kept in memory."""
    path = builders.ball(tmp_path, 1.0, merge=False)
    folder = tmp_path / "store"
    env = dict(os.environ, PYTHONPATH=str(Path(pcmm.__file__).parents[1]) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    proc = subprocess.Popen([sys.executable, "-c", KILLED, str(path), str(folder)], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 120
        while not chunk_path(folder, 2).is_file():
            assert proc.poll() is None, proc.stderr.read().decode()
            assert time.monotonic() < deadline, "no third chunk within 120 s"
            time.sleep(0.02)
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait()
    assert not (folder / "end.json").exists()
    back = pcmm.Trajectory.load(folder)
    chunks = len(list(folder.glob("chunk-*.npz")))
    assert chunks >= 3 and back.status == "partial" and "killed" in back.message
    # every chunk whole: 4 segments each, each ending at an impact whose event is the next chunk's
    assert len(back.segments) == 4 * chunks and len(back.events) == len(back.segments) - 1
    # the same run kept in memory, to the same t_end (the integrator's steps near an event depend
    # on it at round-off), stopped by the event budget past the chunks the killed run wrote
    with pytest.raises(SimulationError, match="more than") as stopped:
        pcmm.simulate(pcmm.load_scene(path), pcmm.RunOptions(t_end=1e6, max_events=len(back.events) + 2))
    kept = stopped.value.partial
    assert list(back.events) == list(kept.events)[:len(back.events)]
    n = len(back.segments)
    np.testing.assert_array_equal(back.t, np.concatenate([s.t for s in kept.segments[:n]]))
    np.testing.assert_array_equal(back.series("q", "Y"), np.concatenate([s.q[:, 0] for s in kept.segments[:n]]))


def test_pcmm_run_store_writes_a_folder_that_loads_and_refuses_a_used_one(tmp_path):
    path = builders.ball(tmp_path, 1.0, merge=False)
    store, summary_path = tmp_path / "run_store", tmp_path / "s.json"
    assert pcmm.cli.main(["run", str(path), "--quiet", "--t-end", "3.0", "--store", str(store),
                          "--summary", str(summary_path)]) == 0
    back = pcmm.Trajectory.load(store)
    written = json.loads(summary_path.read_text())
    assert [e["t"] for e in written["events"]] == [e["t"] for e in back.events]
    assert len(back.events) == 3  # impacts at 0.452, 1.355, 2.258 s (the next at 3.161 s)
    with pytest.raises(UsageError, match="not empty"):
        pcmm.simulate(pcmm.load_scene(path), pcmm.RunOptions(t_end=1.0), store=store)


def test_a_run_stopped_by_an_error_ends_its_store_as_partial_with_its_message(tmp_path):
    """The event budget stops the bouncing ball after its 6th impact (max_events = 5): the store
    ends with status "partial" and the error's message, and holds the 6 events and 6 segments (the fall, then 5 flights) the
    error's own partial trajectory holds."""
    path = builders.ball(tmp_path, 1.0, merge=False)
    folder = tmp_path / "store"
    with pytest.raises(SimulationError, match="more than 5 events") as stopped:
        pcmm.simulate(pcmm.load_scene(path), pcmm.RunOptions(t_end=100.0, max_events=5),
                      store=StoreWriter(folder, chunk_records=4))
    back = pcmm.Trajectory.load(folder)
    assert back.status == "partial" and "more than 5 events" in back.message
    assert (folder / "end.json").is_file() and len(back.events) == 6 and len(back.segments) == 6
    _same_record(stopped.value.partial, back)


def test_pcmm_run_store_stopped_keeps_its_partial_in_the_store_not_a_second_file(tmp_path, monkeypatch, capsys):
    """A stored run stopped by its event budget (the ball's 6th impact, max_events = 5): the
    partial trajectory is the store, ended 'partial' with its 6 events; no <scene>-partial.npz is
    written beside it (that file would load the whole run into memory at once, what --store avoids:
    a 258,000-impact run stopped by SIGTERM rose from 140 MB to 483 MB writing it)."""
    path = builders.ball(tmp_path, 1.0, merge=False, solver={"max_events": 5})
    monkeypatch.chdir(tmp_path)
    store = tmp_path / "run_store"
    assert pcmm.cli.main(["run", str(path), "--quiet", "--t-end", "100.0", "--store", str(store)]) != 0
    err = capsys.readouterr().err
    assert "more than 5 events" in err and f"the partial trajectory is in its store {store}" in err, err
    assert not list(tmp_path.glob("*-partial.npz"))
    back = pcmm.Trajectory.load(store)
    assert back.status == "partial" and len(back.events) == 6 and "more than 5 events" in back.message


def test_a_chunk_header_is_its_json_in_utf8_and_older_string_headers_still_read(tmp_path):
    """A chunk's header (segments, groups, the events' count: JSON) is kept as UTF-8 bytes, one
    byte a character of this ASCII JSON (a numpy string array holds 4, UTF-32), and its events as
    the event log's columns: one float64 row of numbers an event (a bouncing ball's impact: no
    JSON of it, ~1.2 kB an event before).  Chunks written the older ways read the same: the
    events' JSON as UTF-8 bytes (the array ``events``), or in the header, all a numpy string."""
    scene = pcmm.load_scene(builders.ball(tmp_path, 1.0, merge=False))
    folder = tmp_path / "store"
    pcmm.simulate(scene, pcmm.RunOptions(t_end=6.5 * PERIOD), store=StoreWriter(folder, chunk_records=4))
    first = pcmm.Trajectory.load(folder)
    path = chunk_path(folder, 0)
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    text = arrays["header"].tobytes().decode("utf-8")
    header = json.loads(text)
    assert arrays["header"].dtype == np.uint8 and arrays["header"].nbytes == len(text) == len(text.encode("ascii"))
    # the fall and 3 flights, and the 3 impacts between them (the 4th segment's is the next chunk's)
    assert len(header["segments"]) == 4 and header["event_count"] == 3 and "events" not in header
    rows = [arrays[k] for k in arrays if k.startswith("event_rows")]
    assert arrays["event_index"].shape == (3, 2) and len(rows) == 1 and rows[0].shape[0] == 3
    assert list(rows[0][:, 0]) == [e["t"] for e in list(first.events)[:3]]  # an event's "t" leads its row
    events = json.loads(json.dumps(list(first.events)[:3]))
    old = {k: v for k, v in arrays.items() if not k.startswith("event_")}
    np.savez(path, **old, events=np.frombuffer(json.dumps(events).encode(), np.uint8))  # the events' JSON
    _same_record(first, pcmm.Trajectory.load(folder))
    del header["event_count"]
    text = json.dumps({**header, "events": events})
    old["header"] = np.array(text)  # the oldest way: 4 bytes a character, the events in it
    assert old["header"].nbytes == 4 * len(text)
    np.savez(path, **old)
    _same_record(first, pcmm.Trajectory.load(folder))


def test_a_stored_run_reads_no_chunk_back_while_it_goes_on(tmp_path, monkeypatch):
    """A ball (e = 1) bouncing 150 times, stored in chunks of at most 20 segments or events: no
    chunk file is opened while the run goes on (the zero-time-cycle check's last 64 events come
    from the writer's window, the chunk counts from the writer) until the run ends, and the record and summary are
    those of the run kept in memory.  Before the window, every chunk was opened once more when
    written (its counts read back from its header), and the check read the last chunk back."""
    from pcmm.results import store
    from pcmm.run.actions import ZERO_TIME_CYCLE
    assert store.RECENT >= ZERO_TIME_CYCLE
    scene = pcmm.load_scene(builders.ball(tmp_path, 1.0, merge=False))
    opts = pcmm.RunOptions(t_end=150.0 * PERIOD)
    kept = pcmm.simulate(scene, opts)
    opened = []
    real_open = store._open
    monkeypatch.setattr(store, "_open", lambda path: opened.append(path.name) or real_open(path))
    writer = StoreWriter(tmp_path / "store", chunk_samples=10**9, chunk_records=20)
    real_end = writer.end
    monkeypatch.setattr(writer, "end", lambda traj: opened.append("end") or real_end(traj))
    stored = pcmm.simulate(scene, opts, store=writer)
    assert opened[0] == "end"  # (the end's stats read the whole run once more: closest approach, holding)
    opened.clear()
    assert len(kept.events) == 150 and len(list((tmp_path / "store").glob("chunk-*.npz"))) >= 8
    assert stored.events[-ZERO_TIME_CYCLE:] == kept.events[-ZERO_TIME_CYCLE:] and opened == []
    assert stored.events.time(-1) == kept.events[-1]["t"] and opened == []
    _same_record(kept, stored)
    assert _summary_text(stored) == _summary_text(kept)


def test_a_pass_over_a_stored_runs_segments_decodes_none_of_its_events(tmp_path):
    """Reading a stored run's segments (a summary's holding extremes, a plot) leaves each chunk's
    events as their arrays; asking for the events decodes them, the same as the run's."""
    scene = pcmm.load_scene(builders.ball(tmp_path, 1.0, merge=False))
    kept = pcmm.simulate(scene, pcmm.RunOptions(t_end=10.0 * PERIOD))
    pcmm.simulate(scene, pcmm.RunOptions(t_end=10.0 * PERIOD), store=StoreWriter(tmp_path / "store", chunk_records=4))
    back = pcmm.Trajectory.load(tmp_path / "store")
    reader = back.segments.reader
    for k in range(len(reader.paths)):
        assert [s.t[0] for s in reader.chunk(k).segments]
        assert isinstance(reader.chunk(k)._events, dict)  # the arrays, not yet a log
    assert len(reader.paths) >= 3 and len(kept.events) == 10 and list(back.events) == list(kept.events)
