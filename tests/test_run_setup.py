"""What every run sets up again (its views, its configurations' force elements and coordinates)
is done once per process where it is a pure function of the scene: a later run must see exactly
what a first run saw, and nothing one run changes may leak into the next."""
from __future__ import annotations

from builders import Bar, chain_urdf

from pcmm.results.trajectory import urdf_joints


def test_urdf_joints_parsed_once_each_call_its_own_copy():
    text = chain_urdf([Bar(0.5, 1.0), Bar(0.4, 2.0, joint="prismatic", axis=(1.0, 0.0, 0.0))])
    expected = {"J1": {"type": "revolute", "parent": "frame", "child": "link1"},
                "J2": {"type": "prismatic", "parent": "link1", "child": "link2"}}
    first = urdf_joints(text)
    assert first == expected
    first["J1"]["type"] = "changed by a reader"
    del first["J2"]
    again = urdf_joints(text)
    assert again == expected
    assert again is not first and again["J1"] is not first["J1"]


def test_deferred_holds_a_signal_and_puts_back_each_handler_as_it_was():
    """Every recorded segment holds signals back (pcmm.signals.deferred, on the C module's calls):
    a signal meanwhile is held, not acted on; the handler before is back afterwards, the very same
    object; an ignored signal stays ignored throughout (nohup's SIGHUP)."""
    import os
    import signal

    from pcmm.signals import deferred

    seen = []

    def mine(signum, frame):
        seen.append(signum)
    before = signal.signal(signal.SIGTERM, mine), signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        with deferred() as held:
            assert signal.getsignal(signal.SIGHUP) == signal.SIG_IGN
            os.kill(os.getpid(), signal.SIGTERM)
        assert held.received == [signal.SIGTERM] and seen == []
        assert signal.getsignal(signal.SIGTERM) is mine
        assert signal.getsignal(signal.SIGHUP) == signal.SIG_IGN
    finally:
        signal.signal(signal.SIGTERM, before[0])
        signal.signal(signal.SIGHUP, before[1])


def test_force_elements_compiled_once_per_model_and_specs_and_right_for_each(tmp_path):
    """A configuration's force elements are shared by later runs of the same model and specs
    (the same object), and a scene that changes a spring's stiffness gets its own: each run's
    oscillation has the period 2 pi sqrt(I / k) of its own k (a closed form, not the first run's)."""
    import math

    import numpy as np
    from builders import spring_pendulum

    import pcmm
    from pcmm.model.mechanism import Mechanism

    I_c = 0.02
    soft = pcmm.load_scene(spring_pendulum(tmp_path / "soft", k=2.0, I_c=I_c, t_end=0.5))
    stiff = pcmm.load_scene(spring_pendulum(tmp_path / "stiff", k=8.0, I_c=I_c, t_end=0.5))
    a, b = Mechanism(soft)["c1"], Mechanism(soft)["c1"]
    assert a.forces is b.forces  # the second run's set-up reuses the first's
    c = Mechanism(stiff)["c1"]
    assert c.forces is not a.forces
    assert a.forces.K.tolist() == [[2.0]] and c.forces.K.tolist() == [[8.0]]
    for scene, k in ((soft, 2.0), (stiff, 8.0), (soft, 2.0)):
        traj = pcmm.simulate(scene)
        t, q = np.asarray(traj.t), np.asarray(traj.series("q", "J1"))
        assert np.max(np.abs(q - 0.1 * np.cos(math.sqrt(k / I_c) * t))) < 1e-8


def test_a_urdf_edited_between_two_runs_is_recorded_as_it_now_is(tmp_path):
    """The views keep a URDF's text while the file is unchanged; an edit (a new size or
    modification time) is read again, so a run records the file it ran on."""
    import os

    from pcmm.results.trajectory import _view

    path = tmp_path / "m.urdf"
    path.write_text(chain_urdf([Bar(0.5, 1.0)]))
    first = _view(path)
    assert set(first["joints"]) == {"J1"}
    path.write_text(chain_urdf([Bar(0.5, 1.0), Bar(0.3, 1.0)]))
    st = os.stat(path)
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000))  # a later modification, as an editor's
    second = _view(path)
    assert set(second["joints"]) == {"J1", "J2"} and second["urdf"] == path.read_text()
