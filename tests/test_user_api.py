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


def test_a_step_shorter_than_a_controller_period_is_refused_not_run_at_another_test_rate():
    """TR 1 at dt 0.1 ms asks for a step of 0.1 ms; the controller's shortest is one period
    (0.98 ms): the test would run at TR 9.77 without saying so."""
    from hsio.structures import sdof

    fast = sdof(m=0.01, k=2.0, zeta=0.02, dt=1e-4)
    with pytest.raises(hsio.ConfigError, match=r"open_site: test_rate = 1: .* would run the test at TR 9.77, not 1\."):
        hsio.open_site(fast, "emulator://", test_rate=1.0, hold_fraction=0.0, n_avg=1)
    ground = hsio.synthetic_record(duration_s=0.01, dt=1e-4)
    with hsio.open_site(fast, "emulator://", test_rate=10 / 1024 / 1e-4, hold_fraction=0.0, n_avg=1) as site:
        run = hsio.simulate(fast, ground, site)  # ten whole periods a step
    assert run.lab_time_s == pytest.approx(run.steps * 10 / 1024)


def test_hsio_check_refuses_a_test_rate_whose_step_is_shorter_than_a_controller_period(tmp_path):
    from click.testing import CliRunner

    from hsio.cli import main

    config = tmp_path / "fast.toml"
    config.write_text('[structure]\nname = "structure_I"\n[record]\nsynthetic_duration_s = 1.0\n'
                      '[test]\nrate = 0.1\nhold_fraction = 0.0\nn_avg = 1\n')  # 0.5 ms a step at dt 5 ms
    result = CliRunner().invoke(main, ["check", str(config)])
    assert result.exit_code == 2
    assert "fast.toml: [test] rate = 0.1: a step lasts TR x dt" in result.stderr
    assert "Traceback" not in result.stderr


@pytest.mark.parametrize("wrong, words", [
    ({"progress": 5}, r"simulate: progress must be a callable"),
    ({"recorder": "run.sqlite"}, r"simulate: recorder must be a hsio.recording.Recorder"),
    ({"integrator": "frame"}, r"simulate: the integrator was made for structure 'validation', not for 'structure_I'"),
    ({"site": "frame"}, r"simulate: the NumericalSite holds the specimen models of structure 'validation', not of "
                        r"'structure_I'"),
])
def test_simulate_refuses_arguments_for_another_run_before_the_first_step(wrong, words):
    wall, frame = hsio.load_structure("structure_I"), hsio.load_structure("validation")
    ground = hsio.synthetic_record(duration_s=0.2, dt=wall.dt)
    arguments = {"site": hsio.NumericalSite.of(wall), **wrong}
    if wrong.get("integrator") == "frame":
        arguments["integrator"] = hsio.make_integrator(frame)
    if wrong.get("site") == "frame":
        arguments["site"] = hsio.NumericalSite.of(frame)
    with pytest.raises(hsio.ConfigError, match=words):
        hsio.simulate(wall, ground, **arguments)


def test_a_wrong_progress_argument_is_refused_before_an_actuator_moves():
    wall = hsio.load_structure("structure_I")
    ground = hsio.synthetic_record(duration_s=0.2, dt=wall.dt)
    with hsio.open_site(wall, "emulator://", test_rate=10) as site:
        with pytest.raises(hsio.ConfigError, match="progress must be a callable"):
            hsio.simulate(wall, ground, site, progress=True)
        assert not getattr(site, "moved", False)
        run = hsio.simulate(wall, ground, site)  # the site is still at rest: the fixed call runs from there
    assert run.steps == 40


def test_an_integrator_and_a_site_of_an_equal_structure_loaded_twice_are_taken():
    first, second = hsio.load_structure("structure_I"), hsio.load_structure("structure_I")
    ground = hsio.synthetic_record(duration_s=0.2, dt=first.dt)
    run = hsio.simulate(second, ground, hsio.NumericalSite.of(first), integrator=hsio.make_integrator(first))
    assert run.steps == 40
