"""The compiled tree right-hand side (pcmm/compiled.py, pcmm/_tree_dynamics.cpp) is the Python
one, only faster: checked against a second algorithm (the mass matrix by CRBA and the bias by
RNEA, solved densely), against the whole Python run, and in every case where it must step aside."""
from __future__ import annotations

import shutil

import numpy as np
import pinocchio as pin
import pytest

import pcmm
from pcmm.model import compiled
from builders import EXAMPLES, Bar, chain_urdf, copy_example, example_text

# the tests of the compiled evaluations themselves: skipped where they do not run (no extension, or
# PCMM_COMPILED=0, under which the suite checks the Python path: tests/test_python_path.py)
needs_extension = pytest.mark.skipif(compiled._tree_dynamics is None or not compiled.enabled(),
                                     reason=f"the compiled evaluations do not run here: {compiled.why_not()}")

# every joint kind a planar URDF gives Pinocchio, with yawed origins, a fixed joint and gravity
EVERY_KIND = [Bar(0.3, 0.5, yaw=0.4), Bar(0.25, 0.7, axis=(0.0, 0.0, -1.0)),
              Bar(0.2, 0.4, joint="prismatic", axis=(1.0, 0.0, 0.0)),
              Bar(0.2, 0.3, joint="prismatic", axis=(0.0, 1.0, 0.0), yaw=-0.3),
              Bar(0.2, 0.3, joint="prismatic", axis=(0.6, 0.8, 0.0)), Bar(0.1, 0.2, joint="fixed"),
              Bar(0.2, 0.35, com=(0.12, 0.03), izz=0.004)]


def _every_kind_model():
    model = pin.buildModelFromXML(chain_urdf(EVERY_KIND))
    model.gravity.linear[:] = [1.3, -9.81, 0.0]
    return model


def _tree_rhs(model, Q0, KD):
    """The compiled right-hand side, checked by pcmm.model.compiled against Python's pin.aba."""
    data = model.createData()

    def reference(t, y):
        nv = model.nv
        return np.concatenate([y[nv:], pin.aba(model, data, y[:nv], y[nv:], Q0 - KD @ y)])
    return compiled.tree_rhs(model, Q0, KD, reference)


def _by_crba(model, y, Q0, KD):
    """The state derivative by a second algorithm: M(q) a = tau - h(q, v), M by CRBA, h by RNEA."""
    nv = model.nv
    data = model.createData()
    q, v = y[:nv], y[nv:]
    M = pin.crba(model, data, q)
    M = np.triu(M) + np.triu(M, 1).T
    h = pin.rnea(model, data, q, v, np.zeros(nv))
    return np.concatenate([v, np.linalg.solve(M, Q0 - KD @ y - h)])


def test_the_extension_is_built_where_a_compiler_is():
    """pip builds it optionally: a failed build would leave pcmm silently on the slower path."""
    if shutil.which("c++") is None and shutil.which("g++") is None:
        pytest.skip("no C++ compiler here: pcmm runs its Python right-hand side")
    assert compiled._tree_dynamics is not None, compiled.why_not()
    assert compiled._tree_dynamics.PINOCCHIO_VERSION == pin.__version__


@needs_extension
def test_every_joint_kind_against_crba_and_rnea():
    model = _every_kind_model()
    assert {model.joints[j].shortname() for j in range(1, model.njoints)} == {
        "JointModelRZ", "JointModelRevoluteUnaligned", "JointModelPX", "JointModelPY", "JointModelPrismaticUnaligned"}
    nv = model.nv
    rng = np.random.default_rng(7)
    K = np.diag(rng.uniform(0.5, 3.0, nv))
    Dv = rng.uniform(-0.2, 0.2, (nv, nv)) + np.eye(nv)
    Q0, KD = rng.uniform(-1.0, 1.0, nv), np.hstack([K, Dv])
    rhs = _tree_rhs(model, Q0, KD)
    assert rhs is not None, compiled.why_not()
    for _ in range(20):
        y = np.concatenate([rng.uniform(-3.0, 3.0, nv), rng.uniform(-4.0, 4.0, nv)])
        expected = _by_crba(model, y, Q0, KD)
        got = rhs(0.0, y)
        assert got.shape == (2 * nv,)
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12 * (1 + np.abs(expected).max()))
        assert got is not rhs(0.0, y)  # a new array each call: integrators keep the arrays they get


def _branched_model():
    """A tree, not a chain: two branches off the first link (revolute, and prismatic then revolute)
    and a second root, joints in Pinocchio's depth-first order, yawed placements, offset centres."""
    model = pin.Model()
    rng = np.random.default_rng(3)

    def body(parent, joint, xyz):
        j = model.addJoint(parent, joint, pin.SE3(pin.utils.rotate("z", rng.uniform(-1.0, 1.0)), np.array(xyz)),
                           f"j{model.njoints}")
        lever = np.array([rng.uniform(0.0, 0.3), rng.uniform(-0.05, 0.05), 0.0])
        model.appendBodyToJoint(j, pin.Inertia(rng.uniform(0.2, 1.0), lever,
                                               np.diag([1e-3, 1e-3, rng.uniform(1e-3, 1e-2)])), pin.SE3.Identity())
        return j
    a = body(0, pin.JointModelRZ(), [0.0, 0.0, 0.0])
    b = body(a, pin.JointModelRZ(), [0.4, 0.0, 0.0])
    body(b, pin.JointModelRZ(), [0.3, 0.0, 0.0])
    c = body(a, pin.JointModelPX(), [0.2, 0.1, 0.0])
    body(c, pin.JointModelRZ(), [0.1, 0.0, 0.0])
    body(0, pin.JointModelRZ(), [1.0, 0.0, 0.0])
    model.gravity.linear[:] = [0.0, -9.81, 0.0]
    return model


@needs_extension
def test_a_branched_tree_against_crba_and_rnea():
    """The compiled accelerations (aba's passes without its body forces and their sum up the tree)
    where a body's articulated inertia and bias force gather two children's."""
    model = _branched_model()
    assert list(model.parents) == [0, 0, 1, 2, 1, 4, 0]
    nv = model.nv
    rng = np.random.default_rng(1)
    Q0 = rng.uniform(-1.0, 1.0, nv)
    KD = np.hstack([np.diag(rng.uniform(0.5, 3.0, nv)), rng.uniform(-0.2, 0.2, (nv, nv))])
    rhs = _tree_rhs(model, Q0, KD)
    assert rhs is not None, compiled.why_not()
    for _ in range(20):
        y = np.concatenate([rng.uniform(-3.0, 3.0, nv), rng.uniform(-4.0, 4.0, nv)])
        expected = _by_crba(model, y, Q0, KD)
        np.testing.assert_allclose(rhs(0.0, y), expected, rtol=0, atol=1e-12 * (1 + np.abs(expected).max()))


@needs_extension
def test_armature_enters_as_the_python_model_has_it():
    model = _every_kind_model()
    model.armature[:] = np.linspace(0.01, 0.06, model.nv)
    nv = model.nv
    Q0, KD = np.zeros(nv), np.zeros((nv, 2 * nv))
    rhs = _tree_rhs(model, Q0, KD)
    y = np.linspace(-1.0, 1.0, 2 * nv)
    expected = _by_crba(model, y, Q0, KD)  # CRBA puts the armature on M's diagonal
    np.testing.assert_allclose(rhs(0.0, y), expected, rtol=0, atol=1e-12 * (1 + np.abs(expected).max()))
    model.armature[:] = 0.0  # set again: a tree of the model as it is now
    assert np.abs(_tree_rhs(model, Q0, KD)(0.0, y) - expected).max() > 1e-3
    model.gravity.linear[:] = 0.0
    np.testing.assert_allclose(_tree_rhs(model, Q0, KD)(0.0, y),
                               _by_crba(model, y, Q0, KD), rtol=0, atol=1e-12 * (1 + np.abs(expected).max()))


@needs_extension
def test_a_bad_state_is_a_message_not_a_crash():
    model = _every_kind_model()
    nv = model.nv
    rhs = _tree_rhs(model, np.zeros(nv), np.zeros((nv, 2 * nv)))
    with pytest.raises(ValueError, match=f"y has 3 entries, the configuration's state has {2 * nv}"):
        rhs(0.0, np.zeros(3))
    with pytest.raises(TypeError, match="two arguments"):
        rhs(np.zeros(2 * nv))


@needs_extension
def test_it_steps_aside_where_it_would_not_be_the_same_function(monkeypatch):
    """A configuration with a planar joint (nq != nv), a disagreement at the probe states, or
    PCMM_COMPILED=0: the Python right-hand side runs and why_not says why."""
    free = pin.buildModelFromXML(chain_urdf([Bar(0.3, 0.5, joint="planar"), Bar(0.2, 0.3)]))
    assert _tree_rhs(free, np.zeros(free.nv), np.zeros((free.nv, 2 * free.nv))) is None
    assert "only nq == nv > 0 is compiled" in compiled.why_not()

    model = _every_kind_model()
    nv = model.nv
    monkeypatch.setattr(compiled, "AGREEMENT", -1.0)  # nothing agrees: the check is live
    assert _tree_rhs(model, np.ones(nv), np.zeros((nv, 2 * nv))) is None
    assert "disagrees with the Python right-hand side" in compiled.why_not()
    monkeypatch.undo()

    monkeypatch.setenv(compiled.ENV, "0")
    assert not compiled.enabled()
    assert _tree_rhs(model, np.ones(nv), np.zeros((nv, 2 * nv))) is None
    assert compiled.why_not() == "PCMM_COMPILED=0 in the environment"


def test_a_version_mismatch_is_refused_with_the_fix():
    assert compiled.version_problem("4.1.0", "4.1.0") is None
    message = compiled.version_problem("4.1.0", "4.2.0")
    assert "built against Pinocchio 4.1.0" in message and "4.2.0" in message and "reinstall pcmm" in message


@needs_extension
def test_trees_are_built_once_per_model_and_forces():
    model = _every_kind_model()
    nv = model.nv
    Q0, KD = np.zeros(nv), np.zeros((nv, 2 * nv))
    first = _tree_rhs(model, Q0, KD)
    assert _tree_rhs(model, Q0.copy(), KD.copy()).__self__ is first.__self__
    assert _tree_rhs(model, Q0 + 1.0, KD).__self__ is not first.__self__  # other forces: another tree


@needs_extension
@pytest.mark.parametrize("scene", ["three_bar.toml", "three_bar_stop.toml"])
def test_whole_runs_are_the_python_runs(tmp_path, monkeypatch, scene):
    """Example 1 (a mobile impact) and its stop variant (a stable impact): the same events at
    the same times, and the same states, with the compiled right-hand side and without it."""
    path = copy_example(tmp_path, scene, example_text(scene))
    compiled.forget_trees()
    fast = pcmm.simulate(pcmm.load_scene(path))
    # one compiled tree per configuration visited, and the stop's contact's (its normal speed: events/contact.py)
    assert compiled.trees_built() >= len(set(fast.visited())), "a configuration ran the Python right-hand side"
    assert set(fast.stats["evaluations"].values()) == {"compiled"}  # what the run tells its user
    monkeypatch.setenv(compiled.ENV, "0")
    slow = pcmm.simulate(pcmm.load_scene(path))
    assert set(slow.stats["evaluations"].values()) == {"python: PCMM_COMPILED=0 in the environment"}
    assert len(fast.events) >= 1
    assert [e["name"] for e in fast.events] == [e["name"] for e in slow.events]
    for a, b in zip(fast.events, slow.events):
        assert abs(a["t"] - b["t"]) <= 1e-12
    for a, b in zip(fast.segments, slow.segments):
        np.testing.assert_allclose(a.q[-1], b.q[-1], rtol=0, atol=1e-9)
        np.testing.assert_allclose(a.v[-1], b.v[-1], rtol=0, atol=1e-8)


# ---- closed loops: the revolute cut joints' rows (Example 2's double-folded mechanism) -------------------------------
def _loop_coordinates():
    from pcmm.model.mechanism import Mechanism
    scene = pcmm.load_scene(EXAMPLES / "double_folded.toml")
    return Mechanism(scene)["config1"].coords


@needs_extension
def test_closure_rows_are_the_derivatives_of_the_closure():
    """Phi_q is dPhi/dq and the bias is d2Phi/dt2 at zero acceleration, both by central
    differences of the compiled Phi itself (a second route), and both equal the Python binding's."""
    coords = _loop_coordinates()
    assert getattr(coords._point_rows, "__self__", None).__class__.__name__ == "Tree", compiled.why_not()
    nv = coords.nv
    rng = np.random.default_rng(3)
    for _ in range(5):
        q, v = rng.uniform(-np.pi, np.pi, nv), rng.uniform(-2.0, 2.0, nv)
        phi, Jq = coords._point_rows(q)
        assert phi.shape == (coords.closure.size,) and Jq.shape == (coords.closure.size, nv)
        h = 1e-6
        fd = np.column_stack([(coords._point_rows(q + h * e)[0] - coords._point_rows(q - h * e)[0]) / (2 * h)
                              for e in np.eye(nv)])
        np.testing.assert_allclose(Jq, fd, rtol=0, atol=1e-8)
        rows, bias = coords._point_rows_and_bias_at(q, v)
        np.testing.assert_array_equal(rows, Jq)
        h = 1e-4  # along q + v t with a = 0: d2Phi/dt2 = bias
        second = (coords._point_rows(q + h * v)[0] - 2 * phi + coords._point_rows(q - h * v)[0]) / h**2
        np.testing.assert_allclose(bias, second, rtol=0, atol=1e-5 * (1 + np.abs(bias).max()))
        py_phi, py_Jq = coords._python_point_rows(q)
        py_rows, py_bias = coords._python_point_rows_and_bias(q, v)
        np.testing.assert_allclose(phi, py_phi, rtol=0, atol=1e-14)
        np.testing.assert_allclose(Jq, py_Jq, rtol=0, atol=1e-14)
        np.testing.assert_allclose(bias, py_bias, rtol=0, atol=1e-12 * (1 + np.abs(py_bias).max()))
    with pytest.raises(ValueError, match="q has 2 entries"):
        coords._point_rows(np.zeros(2))


@needs_extension
def test_example_2_runs_as_without_it(monkeypatch):
    """47 impacts, then the merge: the same events at the same times with the compiled closure
    rows as with Pinocchio's Python binding."""
    compiled.forget_trees()
    fast = pcmm.simulate(pcmm.load_scene(EXAMPLES / "double_folded.toml"))
    assert compiled.trees_built() >= 1
    assert fast.stats["evaluations"] == {"config1": "compiled", "config2": "compiled"}
    monkeypatch.setenv(compiled.ENV, "0")
    slow = pcmm.simulate(pcmm.load_scene(EXAMPLES / "double_folded.toml"))
    assert len(fast.events) == len(slow.events) >= 40
    assert [e["name"] for e in fast.events] == [e["name"] for e in slow.events]
    assert max(abs(a["t"] - b["t"]) for a, b in zip(fast.events, slow.events)) <= 1e-10


@needs_extension
def test_large_models_stay_on_the_python_evaluations():
    """Above MAX_NV coordinates a compiled tree would hold Pinocchio Data with nv^3-sized tensors
    for a few per cent (aba dominates): refused, with the reason."""
    n = compiled.MAX_NV + 1
    model = pin.buildModelFromXML(chain_urdf([Bar(0.125, 0.2)] * n))
    assert _tree_rhs(model, np.zeros(n), np.zeros((n, 2 * n))) is None
    assert f"nv = {n} > {compiled.MAX_NV}" in compiled.why_not()
    n = compiled.MAX_NV
    model = pin.buildModelFromXML(chain_urdf([Bar(0.125, 0.2)] * n))
    assert _tree_rhs(model, np.zeros(n), np.zeros((n, 2 * n))) is not None


def test_a_configuration_it_cannot_take_says_why_in_the_stats(tmp_path):
    """A free bar on a planar joint (nq = 4, nv = 3) runs the Python right-hand side, and the
    run's stats say so."""
    import builders
    urdf = builders.free_bar_urdf(1.0, 0.5)
    doc = builders.scene_doc({"free": "bar.urdf"}, {"P": [0.0, 0.0, 0.0]}, {"P": [0.1, 0.0, 0.0]})
    path = builders.write_scene(tmp_path, doc, {"bar.urdf": urdf})
    traj = pcmm.simulate(pcmm.load_scene(path), pcmm.RunOptions(t_end=0.05))
    assert traj.stats["evaluations"] == {"free": "python: not compiled: a planar joint"}


def test_without_the_extension_pcmm_runs_the_same_and_says_why(tmp_path):
    """pcmm as pip installs it where there is no C++ compiler: the package without the
    extension. It runs Example 1 to the same latch instant, and says why it is slower."""
    import subprocess
    import sys
    from builders import ROOT
    shutil.copytree(ROOT / "pcmm", tmp_path / "pcmm", ignore=shutil.ignore_patterns("*.so", "__pycache__"))
    # an editable install's finder (setuptools) maps pcmm.model._tree_dynamics to the source tree by name,
    # past the copy's own folder: only the copy may be imported
    script = ("import sys\n"
              "sys.meta_path[:] = [f for f in sys.meta_path if '__editable__' not in getattr(f, '__module__', '')]\n"
              "import pcmm, pcmm.model.compiled as c\n"
              f"t = pcmm.simulate({str(EXAMPLES / 'three_bar.toml')!r})\n"
              "print(repr(t.events[0]['t']))\nprint(c.why_not())\nprint(t.stats['evaluations']['config1'])\n"
              "print(pcmm.__file__)\n")
    out = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, env={**__import__("os").environ,
                         "PYTHONPATH": str(tmp_path)}, capture_output=True, text=True, check=True).stdout.splitlines()
    assert out[3] == str(tmp_path / "pcmm" / "__init__.py")  # the copy, not the installed sources
    assert abs(float(out[0]) - 0.16728511518199546) <= 1e-12
    assert out[1].startswith("pcmm.model._tree_dynamics was not built when pcmm was installed (no C++ compiler?)")
    assert out[2] == "python: " + out[1]
