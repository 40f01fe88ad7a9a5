"""A trial beyond the pose a setup can drive is refused before anything moves (docs/setups.md)."""

import numpy as np
import pytest

import hsio
from hsio.errors import ConfigError, LimitError
from hsio.interfaces import ControlMode
from hsio.structure_file import parse_structure

STEEP = """
[structure]
name = "steep"
dt = 0.01

[[dof]]
name = "x"
mass = 0.01

[[experimental]]
name = "wall"
dofs = ["x"]
actuators = ["act"]
setup = { kind = "one_actuator", length_mm = 500.0, angle_deg = 80.0 }
model = { kind = "matrix", K = [[0.002]] }
"""


def test_a_trial_past_the_singular_pose_is_refused_and_nothing_moves():
    """At 80 degrees the actuator is square to x at u = -86.8 mm, where its stroke is only
    -7.6 mm (well inside the stroke): a trial of -100 mm would be sent as the strokes of the
    mirror pose -73.6 mm, and measured as that. It is refused, naming the element, and the
    actuator keeps its command; a trial on the side of rest moves it."""
    structure = parse_structure(STEEP, "steep.toml")
    with hsio.open_site(structure, "emulator://", test_rate=5) as site:
        site.set_trial(np.array([-20.0]), [ControlMode.DISPLACEMENT])
        before = [g.command for g in site.loop.generators]
        assert site.get_daq().u[0] < -10.0  # on its way (the emulated actuator lags)
        for bad in (-100.0, -86.0):
            with pytest.raises(LimitError, match="element 'wall': trial .* refused"):
                site.set_trial(np.array([bad]), [ControlMode.DISPLACEMENT])
            assert [g.command for g in site.loop.generators] == before


def test_opensees_trial_past_the_singular_pose_is_refused_and_the_session_holds(tmp_path):
    """The same rig served to a genericClient: a trial past the singular pose (its stroke within
    the actuator's) ends the session before anything moves, naming the element; the record keeps
    the committed step."""
    from hsio.recording import Run
    from test_opensees_support import QUIET, RawClient, serving, session_over, wait_for

    (tmp_path / "steep.toml").write_text(STEEP)
    config = tmp_path / "serve.toml"
    config.write_text(f'[structure]\nfile = "{tmp_path / "steep.toml"}"\n[output]\nplots = false\n[test]\nrate = 5\n'
                      f'[opensees]\nelements = ["wall"]\nout = "{tmp_path / "records"}"\n' + QUIET)
    with serving(config) as server:
        client = RawClient(server.ports[0])
        try:
            client.setup()
            client.step(-20.0, 0.01)
            client.send(3, [-100.0], t=0.02)  # setTrialResponse
            client.send(10)  # getForce
            assert client.answered_as_stopped()  # NaN to every request, closed on DIE
        finally:
            client.close()
        assert wait_for(lambda: session_over(server))
    assert any("element 'wall': trial (-100) refused" in line for line in server.lines), server.lines
    record = Run(tmp_path / "records" / "run.sqlite")
    assert record.summary["steps"] == 1 and "past a singular" in record.summary["stopped"]


def test_measured_strokes_that_no_pose_gives_are_implausible_and_name_the_element():
    """Two actuators 500 mm apart cannot differ in stroke by 600 mm: a transducer's spike, not a
    configuration error; the site stops as for any implausible measurement, naming the element.
    So does a stroke that is not a finite number."""
    from hsio.errors import ImplausibleMeasurementError
    from hsio.sites.setup_map import SetupMap

    setups = SetupMap.of(hsio.load_structure("column_two_actuators"))
    with pytest.raises(ImplausibleMeasurementError, match=r"element 'column': the measured strokes \(0, -600\) mm"):
        setups.basic(np.array([0.0, -600.0]), np.zeros(2))
    # a stroke that is not a number (a transducer's dropout), from rest or from the commanded pose;
    # a parallel rig's least squares would carry it on as its displacement
    from hsio.setups import ParallelSetup

    for guess in (None, np.array([1.0, 0.0])):
        with pytest.raises(ImplausibleMeasurementError, match=r"element 'column': the measured strokes \(nan, 0\) mm .* "
                                                              r"not a finite number"):
            setups.basic(np.array([np.nan, 0.0]), np.zeros(2), guess)
    with pytest.raises(ConfigError, match="not a finite number"):
        ParallelSetup([1.0, 1.0]).basic_displacements(np.array([1.0, np.inf]))


def test_a_rotation_of_a_whole_turn_is_refused_not_sent_as_the_pose_at_rest():
    """The strokes of two actuators on a column top repeat with every whole turn: a trial of
    2 pi rad (a model in degrees, a garbled message) has the strokes of the pose at rest, and
    would be measured as 0 rad. It is refused, naming the element, and nothing moves; so is
    1.9 pi, the strokes of -0.1 pi, and a trial that is not a finite number."""
    from hsio.structures import get_structure

    with hsio.open_site(get_structure("column_two_actuators"), "emulator://", test_rate=5) as site:
        site.set_trial(np.array([1.0, 0.001]), [ControlMode.DISPLACEMENT] * 2)
        before = [g.command for g in site.loop.generators]
        for theta in (2 * np.pi, 1.9 * np.pi, -np.pi):
            with pytest.raises(LimitError, match="element 'column': trial .* refused: a rotation of .* half a turn"):
                site.set_trial(np.array([1.0, theta]), [ControlMode.DISPLACEMENT] * 2)
            assert [g.command for g in site.loop.generators] == before

        # a trial that is not a number (a garbled message, a diverged model): a limit, named, not a crash
        for bad in (np.array([np.nan, 0.0]), np.array([1.0, np.inf])):
            with pytest.raises(LimitError, match=r"element 'column': trial \(.*\) refused: it is not a finite pose"):
                site.set_trial(bad, [ControlMode.DISPLACEMENT] * 2)
            assert [g.command for g in site.loop.generators] == before


def test_the_dry_run_refuses_a_record_whose_ns_crosses_a_pose_the_rig_cannot_drive(tmp_path):
    """The steep rig's NS under 0.3 g goes beyond -86.8 mm, square to the actuator, with strokes
    and forces well within the limits: the dry run refuses it, naming the element and the step,
    before anything opens (the site would refuse that trial mid-record). A smaller record passes."""
    from hsio import config, runner

    (tmp_path / "steep.toml").write_text(STEEP)

    def report(pga_g):
        cfg = config.from_dict({"structure": {"file": str(tmp_path / "steep.toml")}, "output": {"plots": False},
                                "record": {"synthetic_duration_s": 3.0, "pga_g": pga_g}, "test": {"rate": 10.0}})
        structure = runner.load_run_structure(cfg)
        ns, rep = runner.predict(cfg, structure, runner.build_record(cfg, structure))
        return ns, rep

    ns, refused = report(0.3)
    assert np.min(ns.u[:, 0]) < -90.0
    assert refused.refused and len(refused.exceeded) == 1, refused.exceeded
    assert refused.exceeded[0].startswith("pose: element 'wall': trial (") and " at step " in refused.exceeded[0]
    ns, passed = report(0.05)
    assert np.max(np.abs(ns.u[:, 0])) > 5.0 and not passed.refused, passed.exceeded
