"""One declaration per solver setting (pcmm.scene.settings): the scene's [solver] schema, RunOptions,
the CLI flags and resolve()'s checks all come from the registry."""
from __future__ import annotations

import math

import pytest

import pcmm
from builders import copy_example
from pcmm.scene import schema, settings
from pcmm.cli import build_parser


@pytest.fixture
def dummy_setting(monkeypatch):
    """A setting no code reads, declared once, as a new setting would be."""
    dummy = settings.Setting("dummy_gain", "number", 2.5, "a gain nothing reads (test only)", schema.positive)
    monkeypatch.setattr(settings, "SETTINGS", settings.SETTINGS + (dummy,))
    return dummy


def _scene(folder, solver_line=None):
    """Example 1 copied into ``folder``, with one more line in its [solver] table."""
    folder.mkdir()
    path = copy_example(folder)
    if solver_line is not None:
        body = path.read_text()
        assert "[solver]" in body
        path.write_text(body.replace("[solver]", f"[solver]\n{solver_line}", 1))
    return path


def test_dummy_setting_reaches_schema_options_resolve_and_cli(dummy_setting, tmp_path, capsys):
    # the scene schema: known key, default, and its check
    assert "dummy_gain" in [k.name for k in settings.solver_keys()]
    assert pcmm.load_scene(_scene(tmp_path / "a")).solver.dummy_gain == 2.5
    assert pcmm.load_scene(_scene(tmp_path / "b", "dummy_gain = 4.0")).solver.dummy_gain == 4.0
    with pytest.raises(pcmm.SceneError, match=r"solver\.dummy_gain: = -1\.0: must be > 0"):
        pcmm.load_scene(_scene(tmp_path / "c", "dummy_gain = -1.0"))
    # the run options: a field, None by default, overriding the scene in resolve()
    options = settings.run_options_type()
    assert options().dummy_gain is None
    scene = pcmm.load_scene(_scene(tmp_path / "d", "dummy_gain = 4.0"))
    assert settings.resolve(scene, options()).dummy_gain == 4.0
    assert settings.resolve(scene, options(dummy_gain=3.0)).dummy_gain == 3.0
    with pytest.raises(pcmm.UsageError, match=r"dummy_gain = 0\.0: must be > 0"):
        settings.resolve(scene, options(dummy_gain=0.0))
    # the CLI: a flag with its help text, checked like the rest
    run = build_parser()._subparsers._group_actions[0].choices["run"]
    help_text = " ".join(run.format_help().split())
    assert "--dummy-gain" in help_text and "a gain nothing reads (test only)" in help_text
    assert run.parse_args(["s.toml", "--dummy-gain", "7.5"]).dummy_gain == 7.5
    with pytest.raises(SystemExit):
        run.parse_args(["s.toml", "--dummy-gain", "-2"])
    assert "dummy-gain = '-2': must be > 0" in capsys.readouterr().err


def test_registry_defaults_are_the_scene_defaults(tmp_path):
    """Every setting's default is what a scene without [solver] gets, and what resolve() returns."""
    scene = pcmm.load_scene(copy_example(tmp_path))
    bare = settings.solver_settings_type()()
    resolved = settings.resolve(scene, pcmm.RunOptions())
    for s in settings.SETTINGS:
        assert getattr(bare, s.name) == s.default
        assert getattr(resolved, s.name) == getattr(scene.solver, s.name)
    assert bare.rtol == 1e-10 and bare.max_step == math.inf and bare.method == "auto"
    assert not hasattr(type(resolved), "__getattr__")  # explicit fields, nothing read through


def test_unknown_method_names_every_choice(tmp_path):
    scene = pcmm.load_scene(copy_example(tmp_path))
    with pytest.raises(pcmm.UsageError) as info:
        settings.resolve(scene, pcmm.RunOptions(method="euler", max_events=0))
    text = str(info.value)
    assert "method = 'euler': must be one of auto, RK45, DOP853" in text and "max_events = 0: must be > 0" in text
