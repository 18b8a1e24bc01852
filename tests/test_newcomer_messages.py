"""Messages a new user met while writing the slider-crank press of tests/test_newcomer_mechanisms.py
(task h-newcomer), each now naming the file, the field and the values at fault."""
from __future__ import annotations

import pytest

import pcmm
from test_newcomer_mechanisms import PAWL_TOML, PAWL_URDF, PRESS_TOML, PRESS_URDF


def _press(tmp_path, old: str, new: str):
    assert old in PRESS_TOML
    (tmp_path / "press.urdf").write_text(PRESS_URDF)
    path = tmp_path / "press.toml"
    path.write_text(PRESS_TOML.replace(old, new, 1))
    return path


def test_a_drive_on_a_kept_loop_coordinate_is_named_at_load(tmp_path):
    """The drive moved from the crank to the crank pin while [initial] independent still keeps the
    crank (and the ram, which is in no loop): the loop involves crank, pin and slide, 2 of them kept
    (crank, and pin by its drive), 1 left for the 2 rows of the cut joint. Before, the assembly failed as a diverged Newton solve and called itself
    "a pcmm defect: please report it"."""
    path = _press(tmp_path, '[[drives]]\njoint = "crank"', '[[drives]]\njoint = "pin"')
    with pytest.raises(pcmm.SceneError) as err:
        pcmm.load_scene(path)
    text = str(err.value)
    assert (f"{path}: initial.independent: = ['crank', 'ram']: the loops of configuration 'free' involve 3 "
            "coordinates (crank, pin, slide), 2 of them kept at t = 0 (crank: independent, pin: driven by "
            "drives[0]), which leaves 1 for the 2 constraint rows of its cut joints (wrist: 2)") in text
    assert "pcmm defect" not in text


def test_drives_alone_are_counted_and_named_at_drives(tmp_path):
    """Without [initial] independent, drives on the crank and the crank pin keep 2 of the loop's 3
    coordinates, leaving 1 for the 2 rows: dependent rows, which may be consistent (constant drives at a
    posture the loop has) or not; here the crank turns, so not: `pcmm check` (the assembly) refuses them,
    naming every row, their rank and the row left violated (the loader counted them and refused at
    `drives`, which would refuse the consistent case too: tests/test_redundant_rows.py). Two drives
    where one is on the ram, in no loop, leave the loop its 2 coordinates: accepted."""
    drive = '[[drives]]\njoint = "crank"'
    pin = '[[drives]]\njoint = "pin"\ncoefficients = [2.6]\n\n'
    ram = '[[drives]]\njoint = "ram"\ncoefficients = [0.27]\nconfigurations = ["free"]\n\n'
    path = _press(tmp_path, drive, ram + drive)
    path.write_text(path.read_text().replace('independent = ["crank", "ram"]\n', ""))
    assert len(pcmm.load_scene(path).drives) == 2
    path = _press(tmp_path, drive, pin + drive)
    path.write_text(path.read_text().replace('independent = ["crank", "ram"]\n', ""))
    from pcmm.run.checks import check_scene
    [problem] = check_scene(pcmm.load_scene(path)).problems
    assert problem.startswith(f"{path}: initial: configuration 'free': at t = 0 s its 4 constraint rows (wrist.fx, "
                              "wrist.fy, pin.drive, crank.drive) are of rank 3 and no posture and motion satisfies "
                              "them all"), problem
    assert "are violated: wrist.f" in problem


def test_kept_crank_and_slider_over_determine_the_loop(tmp_path):
    """[initial] independent keeping both the crank and the slider of a slider-crank leaves the loop
    the crank pin alone for its 2 rows. Before, the assembly blamed a singular posture or redundant
    cut joints."""
    path = _press(tmp_path, 'independent = ["crank", "ram"]', 'independent = ["crank", "slide"]')
    with pytest.raises(pcmm.SceneError) as err:
        pcmm.load_scene(path)
    text = str(err.value)
    assert (f"{path}: initial.independent: = ['crank', 'slide']: the loops of configuration 'free' involve 3 "
            "coordinates (crank, pin, slide), 2 of them kept at t = 0 (crank: independent, slide: independent), "
            "which leaves 1 for the 2 constraint rows of its cut joints (wrist: 2)") in text
    assert "singular" not in text


@pytest.mark.parametrize("old, new, field, value", [
    ("point_b = [0.2, 0.0]", "point_b = [0.2, 0.0, 0.0]", "contact.point_b", "= [0.2, 0.0, 0.0]: must be a list of 2"),
    ("cut = []", 'cut = "pivot"', "cut", "= 'pivot': must be a list"),
    ("contact = {", 'contact = "wall"\nunused = {', "contact", "= 'wall': must be a table"),
])
def test_a_bad_value_is_reported_once_not_also_as_missing(tmp_path, old, new, field, value):
    """A pawl's contact point written with three numbers (or a cut, a contact of the wrong kind) was
    reported twice: as the bad value it is, and again as "missing"."""
    text = PAWL_TOML.replace(old, new, 1)
    if "unused = {" in text:  # the rest of the contact's line, left as a key of its own below
        text = text.replace("unused = {", "# {", 1)
    (tmp_path / "pawl.urdf").write_text(PAWL_URDF)
    path = tmp_path / "pawl.toml"
    path.write_text(text)
    with pytest.raises(pcmm.SceneError) as err:
        pcmm.load_scene(path)
    problems = err.value.problems
    assert len(problems) == 1, problems
    assert problems[0].startswith(f"{path}: transitions[0] (tip strikes wall).{field}: {value}")
