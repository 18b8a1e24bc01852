"""`pcmm graph`: every shipped example's configurations and transitions drawn once each, read
back from the figure's own artists; after a run, each edge's firings are the event table's."""
from __future__ import annotations

import tomllib
from collections import Counter
from pathlib import Path

import pytest

import pcmm
from pcmm.cli import main
from pcmm.results.trajectory import record_views
from pcmm.viz.graph import drawn, graph_figure

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = sorted(ROOT.glob("examples/*.toml"))  # examples/studies/ holds sweep plans, not scenes


def _expected_edges(raw: dict, unmerge_default: bool = True) -> Counter:
    """The edges the TOML declares, counted by hand from its [[transitions]] tables."""
    out = Counter()
    for tr in raw.get("transitions", []):
        kind = tr["type"]
        if kind in ("latch", "pin"):
            out[(tr["name"], kind, tr["from"], tr["to"])] += 1
        elif kind == "release":
            out[(tr["name"], "release", tr["from"], tr["to"])] += 1
        elif kind == "stop":
            out[(tr["name"], "impact", tr["from"], tr["from"])] += 1
            if tr.get("merge_to"):
                out[(tr["name"], "merge", tr["from"], tr["merge_to"])] += 1
                if tr.get("unmerge", raw.get("solver", {}).get("unmerge", unmerge_default)):
                    out[(tr["name"], "release", tr["merge_to"], tr["from"])] += 1
    return out


@pytest.mark.parametrize("path", EXAMPLES, ids=lambda p: p.stem)
def test_each_configuration_and_transition_is_drawn_once(path):
    raw = tomllib.loads(path.read_text())
    scene = pcmm.load_scene(path)
    g = graph_figure(record_views(scene), title=scene.name)
    configs, edge_ids = drawn(g.figure)
    assert sorted(configs) == sorted(raw["configurations"])  # each once
    assert sorted(edge_ids) == list(range(len(g.edges)))  # each edge one artist
    assert Counter((e.name, e.kind, e.source, e.target) for e in g.edges) == _expected_edges(raw)
    labels = [a.get_text() for a in g.figure.findobj() if (a.get_gid() or "").startswith("edge-label:")]
    assert len(labels) == len(g.edges)
    for e, text in zip(g.edges, labels):
        assert text.splitlines()[0] == e.name


@pytest.mark.parametrize("name,t_end", [("three_bar", 1.0), ("three_bar_cycle", 3.3), ("double_folded_cycle", 12.0)])
def test_after_a_run_each_edge_fired_as_often_and_when_the_event_table_says(name, t_end, tmp_path, capsys):
    path = ROOT / "examples" / f"{name}.toml"
    traj = pcmm.simulate(pcmm.load_scene(path), pcmm.RunOptions(t_end=t_end))
    traj.save(tmp_path / "run.npz")
    out = tmp_path / "graph.png"
    assert main(["graph", str(path), "--run", str(tmp_path / "run.npz"), "--out", str(out)]) == 0
    assert out.stat().st_size > 10_000
    assert f"{len(traj.events)} events" in capsys.readouterr().out
    g = graph_figure(traj.views, traj.events)
    # the event table, counted by its own fields
    table = Counter()
    for ev in traj.events:
        kind = ev["transition"] if ev["transition"] in ("latch", "release") else ("merge" if ev["merge"] else "impact")
        table[(ev["name"], kind, ev["from"], ev["to"])] += 1
    assert {(e.name, e.kind, e.source, e.target): len(e.times) for e in g.edges if e.times} == dict(table)
    assert sum(len(e.times) for e in g.edges) == len(traj.events)
    for e in g.edges:
        assert e.times == sorted(e.times)
        if e.times:
            assert f"×{len(e.times)}, t = {e.times[0]:.4g}" in e.label
    configs, edge_ids = drawn(g.figure)
    assert len(configs) == len(set(configs)) and len(edge_ids) == len(g.edges)


def test_a_run_of_another_scene_is_refused_by_name(tmp_path, capsys):
    traj = pcmm.simulate(pcmm.load_scene(ROOT / "examples" / "three_bar.toml"), pcmm.RunOptions(t_end=0.05))
    traj.save(tmp_path / "run.npz")
    assert main(["graph", str(ROOT / "examples" / "andrews.toml"), "--run", str(tmp_path / "run.npz"),
                 "--out", str(tmp_path / "g.png")]) != 0
    err = capsys.readouterr().err
    assert "a run of scene 'three_bar'" in err and "andrews" in err
