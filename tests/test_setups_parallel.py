"""Several actuators on one basic DOF (setup kind ``parallel``, docs/setups.md): strokes
s_i = a_i d / lambda_d, basic force q = lambda_F sum_i a_i f_i, measured d by least squares;
parsed from a structure file with errors naming file, table and key; an emulated wall on two
actuators runs against its NS, each actuator recorded and limit-checked on its own."""

from pathlib import Path

import numpy as np
import pytest

import hsio
from hsio import config, runner
from hsio.emulators.rig import rig_for
from hsio.errors import ConfigError
from hsio.recording import Run, column
from hsio.result import max_error_pct
from hsio.setups import Factors, ParallelSetup, make_setup
from hsio.sites.setup_map import SetupMap

QUIET = {"noise_mm": 0.0, "force_noise_kN": 0.0, "resolution_mm": 0.0, "force_resolution_kN": 0.0}

WALL = """
[structure]
name = "wall_two_actuators"
dt = 0.01

[[dof]]
name = "top"
mass = 0.02

[damping]
kind = "mass"
zeta = 0.02

[[experimental]]
name = "wall"
dofs = ["top"]
{actuators}
setup = {setup}
model = {{ kind = "linear", k = 4.0 }}
"""


def _wall(tmp_path: Path, setup='{ kind = "parallel", ratios = [1.0, 1.0] }',
          actuators='actuators = ["east", "west"]') -> Path:
    path = tmp_path / "wall.toml"
    path.write_text(WALL.format(setup=setup, actuators=actuators))
    return path


def test_strokes_forces_and_inverse_in_closed_form():
    a = np.array([1.0, -0.5, 2.0])
    setup = ParallelSetup(a.tolist(), Factors(displacement=2.0, force=3.0))
    d = np.array([7.0])  # model mm
    np.testing.assert_allclose(setup.strokes(d), a * 7.0 / 2.0, rtol=1e-15)
    np.testing.assert_allclose(setup.linearised_strokes(d), setup.strokes(d), rtol=1e-15)
    np.testing.assert_allclose(setup.basic_displacements(setup.strokes(d)), d, rtol=1e-12)
    f = np.array([10.0, -4.0, 2.5])
    # q = lambda_F sum a_i f_i, whatever the displacement factor
    assert setup.basic_forces(f, d)[0] == pytest.approx(3.0 * (10.0 + 2.0 + 5.0), rel=1e-14)
    # strokes that disagree: their least-squares displacement, d = lambda_d (a . s) / (a . a)
    s = np.array([1.0, 0.0, 0.0])
    assert setup.basic_displacements(s)[0] == pytest.approx(2.0 * 1.0 / 5.25, rel=1e-14)
    assert setup.pose_problem(np.array([1e5])) == ""


def test_the_setup_map_splits_a_basic_force_by_the_ratios():
    setup = make_setup({"kind": "parallel", "ratios": [1.0, 3.0]}, 1)

    class Element:
        name, actuator_names = "beam", ["near", "far"]

        def make_setup(self):
            return setup

    smap = SetupMap([Element()])
    assert (smap.n_channels, smap.n_actuators) == (1, 2)
    f = smap.forces_for(np.array([50.0]), np.array([2.0]))
    np.testing.assert_allclose(f, [5.0, 15.0], rtol=1e-12)  # least norm: a q / (a . a)
    u, q = smap.basic(np.array([2.0, 6.0]), f)
    np.testing.assert_allclose([u[0], q[0]], [2.0, 50.0], rtol=1e-12)
    # the recorded channel samples: stroke by the pseudo-inverse, force as the weighted sum
    samples = np.array([[[2.0, 2.0, 5.0], [6.0, 6.0, 15.0]]])
    np.testing.assert_allclose(smap.linearised_samples(samples)[0, 0], [2.0, 2.0, 50.0], rtol=1e-12)


def test_the_rig_closes_on_the_strokes_and_carries_k_d(tmp_path):
    structure = hsio.load_structure(_wall(tmp_path, '{ kind = "parallel", ratios = [1.0, -0.5] }'))
    (element,) = structure.experimental
    assert element.actuator_names == ("east", "west")
    rig = rig_for(element, QUIET, seed=0)
    setup = element.make_setup()
    for i, s in reversed(list(enumerate(setup.strokes(np.array([12.0]))))):  # leg 0 last: it evaluates
        rig.leg_force(i, s)
    assert rig.pose[0] == pytest.approx(12.0, rel=1e-12)
    np.testing.assert_allclose(rig.forces, np.array([1.0, -0.5]) * 48.0 / 1.25, rtol=1e-12)
    assert rig.forces @ np.array([1.0, -0.5]) == pytest.approx(4.0 * 12.0, rel=1e-12)


def test_default_actuator_names_one_per_ratio(tmp_path):
    structure = hsio.load_structure(_wall(tmp_path, '{ kind = "parallel", ratios = [1.0, 1.0, 0.5] }', ""))
    assert structure.experimental[0].actuator_names == ("wall.0", "wall.1", "wall.2")


@pytest.mark.parametrize("setup, where", [
    ('{ kind = "parallel" }', "experimental[0].setup.ratios: missing"),
    ('{ kind = "parallel", ratios = 1.0 }', "experimental[0].setup.ratios: got 1.0"),
    ('{ kind = "parallel", ratios = [1.0] }', "experimental[0].setup.ratios: must give 2 to 16"),
    ('{ kind = "parallel", ratios = [1.0, 0.0] }', "experimental[0].setup.ratios[1]: must be a number"),
    ('{ kind = "parallel", ratios = [1.0, nan] }', "experimental[0].setup.ratios[1]: must be a number"),
    ('{ kind = "parallel", ratios = [true, 1.0] }', "experimental[0].setup.ratios[0]: must be a number"),
    ('{ kind = "parallel", ratios = [1.0, 1.0, 1.0] }', "experimental[0].actuators: 2 actuator(s); setup 'parallel' drives 3"),
    ('{ kind = "parallel", ratios = [1.0, 1.0], length_mm = 1.0 }', "experimental[0].setup.length_mm: unknown key"),
])
def test_errors_name_the_file_table_and_key(tmp_path, setup, where):
    path = _wall(tmp_path, setup)
    with pytest.raises(ConfigError) as info:
        hsio.load_structure(path)
    assert str(info.value).startswith(f"{path}: {where}"), str(info.value)


def test_a_wall_on_two_actuators_matches_its_ns(tmp_path):
    structure = hsio.load_structure(_wall(tmp_path, '{ kind = "parallel", ratios = [1.0, 0.5] }'))
    ground = hsio.synthetic_record(duration_s=2.0, dt=structure.dt, pga_g=0.3, seed=3)
    ns = hsio.run_numerical(structure, ground)
    with hsio.open_site(structure, "emulator://", test_rate=10) as site:
        hs = hsio.simulate(structure, ground, site)
        feedback = site.last_actuator_feedback
    error, _ = max_error_pct(hs.u, ns.u)
    assert error < 2.0 and np.max(np.abs(ns.u)) > 5.0
    # each actuator at its own stroke, and their weighted force is the wall's k d
    d = hs.measured_displacement[-1, 0]
    np.testing.assert_allclose(feedback.displacement, np.array([1.0, 0.5]) * d, atol=0.05)
    assert feedback.force @ np.array([1.0, 0.5]) == pytest.approx(4.0 * d, abs=0.05)
    assert hs.measured_force[-1, 0] == pytest.approx(feedback.force @ np.array([1.0, 0.5]), rel=1e-9)


def test_hsio_run_records_and_limits_each_actuator(tmp_path):
    wall = _wall(tmp_path, '{ kind = "parallel", ratios = [1.0, 0.5] }')
    cfg = config.from_dict({"structure": {"file": str(wall)}, "output": {"plots": False},
                            "record": {"synthetic_duration_s": 1.0, "pga_g": 0.3}, "test": {"rate": 10.0}})
    summary = runner.run(cfg, tmp_path / "run")
    assert summary["max_error_pct"] < 2.0
    run = Run(tmp_path / "run" / "run.sqlite")
    assert run.actuator_names == ["wall.top"]  # the channel, through the linearised geometry
    # each actuator's own target, command, stroke and force, every step
    table = run.table("actuators")
    assert len(table["step"]) == summary["steps"]
    np.testing.assert_allclose(table["target_west"], 0.5 * table["target_east"], rtol=1e-12)
    np.testing.assert_allclose(table["disp_west"], 0.5 * table["disp_east"], atol=0.05)
    weighted = table["force_east"] + 0.5 * table["force_west"]
    np.testing.assert_allclose(weighted, run.steps[column("force", "wall.top")], rtol=1e-9, atol=1e-9)
    assert np.max(np.abs(table["force_east"])) > 10.0
    # the dry run checks each actuator: a ratio of 8 takes the west one past its stroke limit alone
    far = _wall(tmp_path, '{ kind = "parallel", ratios = [1.0, 8.0] }')
    cfg = config.from_dict({"structure": {"file": str(far)}, "output": {"plots": False},
                            "record": {"synthetic_duration_s": 3.0, "pga_g": 0.3}, "test": {"rate": 10.0}})
    structure = runner.load_run_structure(cfg)
    _, report = runner.predict(cfg, structure, runner.build_record(cfg, structure))
    assert report.refused
    assert report.exceeded and all("west" in e and "east" not in e for e in report.exceeded), report.exceeded


WOOD = """
[structure]
name = "wood_two_actuators"
dt = 0.005

[[dof]]
name = "wall"
mass = 0.011

[damping]
kind = "mass"
zeta = 0.05

[[instrument]]
name = "top_lvdt"
kind = "lvdt"
element = "wall"

[[experimental]]
name = "wall"
dofs = ["wall"]
actuators = ["east", "west"]
setup = {setup}
model = {{ kind = "pinched_wood", k0 = 2.6, F0 = 30.0, r1 = 0.05, r3 = 1.5, r4 = 0.02, r_pinch = 0.15 }}
{external}
"""
LVDT = 'displacement_from = "top_lvdt"\nouter_loop = { tolerance_mm = 0.05, max_iterations = 4 }'


def test_an_lvdt_on_a_wall_pushed_by_two_actuators_takes_out_the_load_trains(tmp_path):
    """Structure I's wood wall pushed by two actuators side by side, each behind a load train of
    0.1 mm/kN (0.05 mm/kN together): on the actuators' transducers HS is about 15 % off its NS;
    with the wall's LVDT and the outer loop, whose corrections move both actuators by their
    ratios, it is back within 2 %."""
    setup = '{ kind = "parallel", ratios = [1.0, 1.0] }'
    (tmp_path / "plain.toml").write_text(WOOD.format(setup=setup, external=""))
    (tmp_path / "lvdt.toml").write_text(WOOD.format(setup=setup, external=LVDT))
    plain, lvdt = hsio.load_structure(tmp_path / "plain.toml"), hsio.load_structure(tmp_path / "lvdt.toml")
    ground = hsio.synthetic_record(duration_s=1.5, dt=plain.dt, pga_g=0.3, seed=1)
    ns = hsio.run_numerical(plain, ground)
    errors, runs = {}, {}
    for label, structure in (("compliant", plain), ("lvdt", lvdt)):
        with hsio.open_site(structure, "emulator://", test_rate=5, options={"compliance_mm_per_kN": 0.1}) as site:
            runs[label] = hsio.simulate(structure, ground, site)
            feedback = site.last_actuator_feedback
        errors[label] = max_error_pct(runs[label].u, ns.u)[0]
    assert errors["compliant"] > 5.0 and errors["lvdt"] < 2.0, errors
    iterations = [row[1] for row in runs["lvdt"].instrument_log]
    assert max(iterations) >= 1 and max(iterations) <= 4
    # the element's displacement is the LVDT's reading, and both rods went past it alike
    readings = np.array([row[2]["top_lvdt"] for row in runs["lvdt"].instrument_log])
    np.testing.assert_allclose(runs["lvdt"].measured_displacement[1:, 0], readings, atol=1e-12)
    assert feedback.commands[0] == pytest.approx(feedback.commands[1], abs=1e-9)


@pytest.mark.parametrize("setup, message", [
    ('{ kind = "two_actuators", length_mm = 1500.0, spacing_mm = 500.0 }', "elements without setups or with a 'parallel' one"),
    ('{ kind = "parallel", ratios = [1.0, 1.0], factors = { displacement = 0.5 } }', "displacement factor must be 1"),
])
def test_an_external_displacement_elsewhere_is_refused_not_ignored(tmp_path, setup, message):
    text = WOOD.format(setup=setup, external=LVDT)
    if "two_actuators" in setup:
        text = text.replace('dofs = ["wall"]', 'dofs = ["wall", "rot"]').replace(
            "model = {", 'model = { kind = "matrix", K = [[2.6, 0.0], [0.0, 1.0e5]] }\n#').replace(
            "[damping]", '[[dof]]\nname = "rot"\nmass = 1.0\niota = 0.0\n\n[damping]')
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        hsio.load_structure(path)
    assert str(info.value).startswith(f"{path}: experimental[0].displacement_from: ") and message in str(info.value)


def test_emulated_instruments_on_a_scaled_parallel_rig_read_the_lab_s_units(tmp_path):
    """An LVDT and a load cell on a wall of displacement factor 2 and force factor 3 read
    the lab's DOF, d_lab = d / lambda_d (each rod's stroke over its ratio) and Q_lab = sum a_i f_i
    (= q / lambda_F), as a real instrument on the rig does, not the model's d and q (within the
    rods' motion between the trial's end and the reading)."""
    from hsio.interfaces import ControlMode

    setup = '{ kind = "parallel", ratios = [1.0, 0.5], factors = { displacement = 2.0, force = 3.0 } }'
    text = _wall(tmp_path, setup).read_text() + (
        '\n[[instrument]]\nname = "lvdt"\nkind = "lvdt"\nelement = "wall"\nnoise = 0.0\nresolution = 0.0\n'
        '\n[[instrument]]\nname = "cell"\nkind = "load_cell"\nelement = "wall"\nnoise = 0.0\nresolution = 0.0\n')
    (tmp_path / "scaled.toml").write_text(text)
    structure = hsio.load_structure(tmp_path / "scaled.toml")
    with hsio.open_site(structure, "emulator://", test_rate=10, options=QUIET) as site:
        site.set_trial(np.array([20.0]), [ControlMode.DISPLACEMENT])  # model mm: 10 lab mm
        readings = site.read_instruments()
        fb = site.last_actuator_feedback
        u, R = site.get_daq().u[0], site.get_daq().R[0]
    a = np.array([1.0, 0.5])
    assert u > 15.0  # the rods went most of the way
    # the rods' least-squares stroke and the ratio-weighted load cells: lab mm and kN
    assert readings["lvdt"] == pytest.approx(float(a @ fb.displacement) / float(a @ a), rel=0.01)
    assert readings["cell"] == pytest.approx(float(a @ fb.force), rel=0.01)
    # half the model's displacement and a third of its force
    assert readings["lvdt"] == pytest.approx(u / 2.0, rel=0.01)
    assert readings["cell"] == pytest.approx(R / 3.0, rel=0.01)
