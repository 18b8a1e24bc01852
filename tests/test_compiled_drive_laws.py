"""The drive laws the compiled evaluations read (``read_drive_laws`` in pcmm/model/_tree_dynamics.cpp,
shared by ``Tree.set_drives`` and the loops' ``Loop``): one law per driven coordinate, each a
distinct coordinate, each law the (f, f', f'') coefficients; a bad one is a ValueError naming the
caller and what is wrong.  The laws read are the laws evaluated: a loop driven by q_0 = t^2 reads
f = t^2, f' = 2 t, f'' = 2 in its drive row's residual and bias, checked against the law by hand."""
from __future__ import annotations

import builders
import numpy as np
import pytest

import pcmm
from pcmm.model import compiled
from pcmm.model.mechanism import Mechanism

needs_extension = pytest.mark.skipif(not compiled.enabled() or not hasattr(compiled._tree_dynamics, "Loop"),
                                     reason=f"the compiled loops are not here: {compiled.why_not()}")


def _loop_tree(tmp_path):
    """The compiled tree of a parallelogram four-bar's loop (3 coordinates, cut joint C), no drives."""
    coords = Mechanism(pcmm.load_scene(builders.parallelogram(tmp_path, 0.5, 2.0)))["c"].coords
    forces = coords.forces
    built = compiled.loop_tree(coords.cfg.model, coords.closure.frames_a, coords.closure.frames_b, forces.Q0,
                               forces.KD, forces.points)
    assert built is not None, compiled.why_not()
    (tree, _), springs = built
    return coords, tree, springs


SQUARE = ((0.0, 0.0, 1.0), (0.0, 2.0), (2.0,))  # f = t^2: (f, f', f'') coefficients, low order first


@needs_extension
@pytest.mark.parametrize("driven, laws, message", [
    ((0, 0), (SQUARE, SQUARE), "Loop: coordinate 0 is not one of the 3 coordinates, or is driven twice"),
    ((3,), (SQUARE,), "Loop: coordinate 3 is not one of the 3 coordinates, or is driven twice"),
    ((-1,), (SQUARE,), "Loop: coordinate -1 is not one of the 3 coordinates, or is driven twice"),
    ((0, 1), (SQUARE,), "Loop: one law per driven coordinate"),
    ((0,), (SQUARE[:2],), r"Loop: a law is \(f, f', f''\) coefficients"),
])
def test_a_loop_refuses_a_bad_drive_law_naming_what_is_wrong(tmp_path, driven, laws, message):
    """Before the loops read their laws with set_drives' reader, a coordinate driven twice was taken
    (two rows q_0 - f(t): a singular KKT system at every evaluation)."""
    _, tree, springs = _loop_tree(tmp_path)
    with pytest.raises(ValueError, match=message):
        compiled._tree_dynamics.Loop(tree, driven, laws, springs)


@needs_extension
def test_set_drives_refuses_a_bad_drive_law_naming_what_is_wrong(tmp_path):
    """The same reader behind Tree.set_drives (its own name in the message), and no drive at all."""
    model = Mechanism(pcmm.load_scene(builders.pendulum(tmp_path, 0.5)))["c1"].model
    tree = compiled._rebuild(model)
    tree.finalize(model.gravity.linear, np.zeros(1), np.zeros((1, 2)))
    with pytest.raises(ValueError, match="set_drives: coordinate 0 is not one of the 1 coordinates, or is driven twice"):
        tree.set_drives((0, 0), (SQUARE, SQUARE))
    with pytest.raises(ValueError, match="set_drives: at least one driven coordinate"):
        tree.set_drives((), ())
    with pytest.raises(ValueError, match="set_drives: one law per driven coordinate"):
        tree.set_drives((0,), ())


@needs_extension
def test_a_loop_evaluates_the_law_it_read(tmp_path):
    """Loop(tree, (0,), (t^2 law,)): its rows at (t, q, v) are the cut joint's two rows and the drive's
    unit row on coordinate 0, whose bias is -f''(t) = -2 (``Phi_q a + bias = 0`` with Phi = q_0 - t^2)."""
    coords, tree, springs = _loop_tree(tmp_path)
    loop = compiled._tree_dynamics.Loop(tree, (0,), (SQUARE,), springs)
    loop.seed(np.array([0.5, -0.5, 0.5]), np.zeros(0, int), np.array([0, 1, 2]))
    t = 0.7
    q = np.array([0.49, -0.49, 0.49])  # on the law (q_0 = t^2) and on the parallelogram branch
    v = np.array([1.4, -1.4, 1.4])  # f'(0.7) = 1.4
    kkt = loop.kkt(t, q, v)
    assert kkt is not None
    a, lam, Jq, bias = kkt
    np.testing.assert_array_equal(Jq[2], [1.0, 0.0, 0.0])
    assert bias[2] == -2.0
    np.testing.assert_allclose(a[0], 2.0, rtol=0, atol=1e-12)  # the drive row: a_0 = f''(t)
