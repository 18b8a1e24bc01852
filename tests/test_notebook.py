"""The example notebook runs: Example 1, its inline replay, its figures and a restitution sweep.

Executed with nbclient in a fresh kernel (the test's own Python, so the checked-out pcmm),
from the ``examples/`` folder as a reader would run it.
"""
from __future__ import annotations

import math
import re
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # executes the example notebook in a Jupyter kernel

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")
pytest.importorskip("matplotlib")

NOTEBOOK = Path(__file__).resolve().parents[1] / "examples" / "example1.ipynb"


@pytest.fixture(scope="module")
def executed():
    nb = nbformat.read(NOTEBOOK, as_version=4)
    client = nbclient.NotebookClient(nb, timeout=120, kernel_name="python3",
                                     resources={"metadata": {"path": str(NOTEBOOK.parent)}})
    client.execute()  # jupyter_client starts the "python3" kernel with this interpreter
    return nb


def _outputs(nb, kind):
    for cell in nb.cells:
        for out in cell.get("outputs", []):
            data = out.get("data", {})
            if kind in data:
                yield data[kind]
            elif kind == "text/plain" and out.get("output_type") == "stream":
                yield out["text"]


def test_notebook_shows_the_replay_inline(executed):
    pages = [h for h in _outputs(executed, "text/html") if 'class="pcmm-replay"' in h]
    assert len(pages) == 1
    page = pages[0]
    assert page.startswith('<iframe class="pcmm-replay" srcdoc="<!DOCTYPE html>')  # the page itself, no server
    assert "new MeshCat.Viewer" in page and "PCMM_COMMANDS" in page
    # the two runs overlaid, the latch on the timeline of each
    assert len(re.findall(r'class=&quot;pcmm-row&quot;', page)) == 2
    assert len(re.findall(r'class=&quot;pcmm-marker pcmm-merge&quot;', page)) == 2


def test_notebook_shows_the_figures(executed):
    pngs = list(_outputs(executed, "image/png"))
    assert len(pngs) == 3  # energy, relative angles, the sweep
    text = "".join(_outputs(executed, "text/plain"))
    assert "'energy'" in text and "'impulses'" in text


def test_restitution_sweep_obeys_newtons_law(executed):
    text = "".join(_outputs(executed, "text/plain"))
    rows = [(float(e), float(r), float(lost)) for e, r, lost in
            re.findall(r"e = ([0-9.]+): rebound ratio ([-0-9.]+), kinetic energy lost ([-0-9.]+) J", text)]
    assert [e for e, _, _ in rows] == [0.0, 0.25, 0.5, 0.8, 1.0]
    lost0 = rows[0][2]
    assert lost0 > 0
    for e, ratio, lost in rows:
        assert math.isclose(ratio, e, abs_tol=2e-6), (e, ratio)  # Newton's restitution law
        assert math.isclose(lost, lost0 * (1 - e * e), abs_tol=2e-6), (e, lost)  # energy lost ~ 1 - e^2
    assert re.search(r"O3 latches: t = 0\.16728\d\d s, impulse 0\.3309\d N s", text), text[:300]
