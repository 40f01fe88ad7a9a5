"""hsio as a library in a notebook: calls with arguments a user gets wrong."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")

import pytest  # noqa: E402

import hsio  # noqa: E402


@pytest.fixture(scope="module")
def runs():
    wall = hsio.load_structure("structure_I")
    frame = hsio.load_structure("validation")
    return (hsio.run_numerical(wall, hsio.synthetic_record(duration_s=0.3, dt=wall.dt)),
            hsio.run_numerical(frame, hsio.synthetic_record(duration_s=0.3, dt=frame.dt)))


@pytest.mark.parametrize("reference, words", [
    ("frame", r"plot: the reference is a run of other DOFs \(C1, C2; this run: wall\)"),
    ("array", r"plot: reference must be a Result .*got ndarray"),
])
def test_plot_against_a_reference_that_is_not_a_run_of_the_same_dofs_is_refused(runs, reference, words):
    wall, frame = runs
    with pytest.raises(hsio.HsioError, match=words):
        wall.plot(reference=frame if reference == "frame" else wall.u)


@pytest.mark.parametrize("where, words", [
    ("folder", r"is a folder; give the image file's path"),
    ("missing/hs.png", r"cannot write .*missing/hs.png: No such file or directory"),
    ("hs.xyz", r"cannot write .*hs.xyz: Format 'xyz' is not supported"),
])
def test_plot_to_a_path_that_cannot_be_written_names_it(runs, tmp_path, where, words):
    (tmp_path / "folder").mkdir()
    with pytest.raises(hsio.HsioError, match=words):
        runs[0].plot(tmp_path / where)
    assert not (tmp_path / "folder.png").exists()
