"""An element that takes its displacement from an external instrument (docs/setups.md): the
instrument's reading is the element's measured displacement whatever else the site does with the
actuators' samples (a secant estimator, as the implicit methods of `hsio run` use), and under
relative trials the instrument's reading at enabling is its zero, as the actuators' positions are
theirs."""

import numpy as np
import pytest

import hsio
from hsio.clock import LockstepClock
from hsio.errors import ConfigError
from hsio.control_loop import ControlLoop
from hsio.emulators.local import open_instruments, open_url
from hsio.result import max_error_pct
from hsio.secant import SecantEstimator
from hsio.sites import ActuatorSite
from hsio.structure_file import parse_structure
from hsio.structures import Damping, ExperimentalElement, Instrument, OuterLoop, Structure
from test_instruments_readback import TEXT, Installed

# A linear wall whose actuator transducer reads 10 % short (gain 0.9): only the LVDT reads the truth.
WALL = """
[structure]
dt = 0.005
[[dof]]
name = "wall"
mass = 0.011
[damping]
kind = "mass"
zeta = 0.05
[[experimental]]
name = "wall"
dof = "wall"
K_EI = 2.0
{source}
model = {{ kind = "linear", k = 2.6 }}
[[instrument]]
name = "lvdt"
kind = "lvdt"
element = "wall"
"""


@pytest.mark.parametrize("method", ["implicit_dc", "force_control"])
def test_the_instrument_is_the_displacement_with_a_secant_estimator(method):
    lvdt = parse_structure(WALL.format(source='displacement_from = "lvdt"'), "wall.toml")
    transducer = parse_structure(WALL.format(source=""), "wall.toml")
    ground = hsio.synthetic_record(duration_s=1.5, dt=lvdt.dt, pga_g=0.3, seed=1)
    ns = hsio.run_numerical(transducer, ground, method=method)
    errors = {}
    for label, structure in (("lvdt", lvdt), ("transducer", transducer)):
        with hsio.open_site(structure, "emulator://", test_rate=20, options={"displacement_gain": 0.9},
                            estimator=SecantEstimator("average", 16, 0.1)) as site:
            hs = hsio.simulate(structure, ground, site, method=method)
        errors[label] = max_error_pct(hs, ns)[0]
    assert errors["transducer"] > 20.0  # the gain error does the damage
    assert errors["lvdt"] < 2.0



def offset_site(external):
    """A specimen installed with the actuator and the string pot at 7.5 mm; relative trials."""
    structure = parse_structure(TEXT, "offset.toml")
    clock = LockstepClock()
    actuators = open_url("emulator://", structure.experimental, clock, {"noise_mm": 0.0, "resolution_mm": 0.0})
    controller = actuators[0].controller
    controller.specimen = Installed(1.5, 7.5)
    controller.set_command(7.5)
    controller.advance(600)
    loop = ControlLoop(actuators, clock, structure.dt, 10.0, n_avg=4, hold_fraction=0.5)
    daq = open_instruments(structure.instruments, structure.experimental, actuators)
    return structure, controller, ActuatorSite(loop, instruments=daq, external=external, relative=True)


@pytest.mark.parametrize("outer_loop", [None, OuterLoop(0.05, 4)], ids=["reading", "outer loop"])
def test_relative_trials_zero_the_instrument_at_enabling(outer_loop):
    structure, controller, site = offset_site([("x_pot", outer_loop)])
    ground = hsio.synthetic_record(duration_s=1.5, dt=structure.dt, pga_g=0.3, seed=3)
    ns = hsio.run_numerical(structure, ground)
    with site:
        assert site.committed()[0][0] == pytest.approx(0.0, abs=1e-3)
        hs = hsio.simulate(structure, ground, site)
    # no jump back to the instrument's own zero: the first commands are those of the record
    assert np.all(np.abs(hs.commands[:3, 0]) < 0.5)
    assert abs(hs.measured_displacement[1, 0]) < 0.5
    assert max_error_pct(hs.u, ns.u)[0] < 2.0
    readings = np.array([r["x_pot"] for _, _, r in site.instrument_log])
    np.testing.assert_allclose(readings - 7.5, hs.measured_displacement[1:, 0], atol=0.02)  # logged as read


# A column on two actuators beside a wall read by its own LVDT, and a held axial preload.
RIG = """
[structure]
dt = 0.01
[[dof]]
name = "top_x"
mass = 0.01
[[dof]]
name = "top_rot"
mass = 900.0
iota = 0.0
[[dof]]
name = "side"
mass = 0.01
[damping]
kind = "rayleigh"
zeta = 0.02
[[spring]]
dof = "side"
to = "top_x"
k = 0.5
[[experimental]]
name = "column"
dofs = ["top_x", "top_rot"]
setup = { kind = "two_actuators", length_mm = 1500.0, spacing_mm = 500.0 }
model = { kind = "cantilever", EI = 2.0e9, L = 2000.0 }
[[experimental]]
name = "wall"
dof = "side"
displacement_from = "lvdt"
outer_loop = { tolerance_mm = 0.002, max_iterations = 3 }
model = { kind = "linear", k = 1.5 }
[[instrument]]
name = "lvdt"
kind = "lvdt"
element = "wall"
"""


def test_an_element_beside_a_setup_takes_its_instrument_and_closes_its_outer_loop():
    structure = parse_structure(RIG, "rig.toml")
    ground = hsio.synthetic_record(duration_s=1.0, dt=structure.dt, pga_g=0.3, seed=2)
    ns = hsio.run_numerical(structure, ground)
    with hsio.open_site(structure, "emulator://", test_rate=10) as site:
        hs = hsio.simulate(structure, ground, site)
    assert max_error_pct(hs, ns)[0] < 2.0
    iterations = np.array([n for _, n, _ in hs.instrument_log])
    readings = np.array([r["lvdt"] for _, _, r in hs.instrument_log])
    wall = structure.experimental_dofs.index(2)
    np.testing.assert_array_equal(hs.measured_displacement[1:, wall], readings)  # the LVDT, not the transducer
    assert iterations.max() > 0  # the outer loop corrected the wall's actuator
    converged = iterations < 3
    assert np.all(np.abs(readings - hs.targets[1:, wall])[converged] <= 0.002 + 1e-12)


TWO = """
[structure]
dt = 0.01
[[dof]]
name = "x"
mass = 0.01
[[dof]]
name = "y"
mass = 0.02
[[experimental]]
name = "w"
dof = "x"
{w}
model = {{ kind = "linear", k = 1.0 }}
[[experimental]]
name = "v"
dof = "y"
{v}
model = {{ kind = "linear", k = 3.0 }}
[[instrument]]
name = "l"
kind = "lvdt"
{element}
{scale}
"""


@pytest.mark.parametrize("fields, message", [
    (dict(w='displacement_from = "l"', element='element = "v"'),
     r"experimental\[0\]\.displacement_from: instrument 'l' reads element 'v', not 'w'"),
    (dict(w='displacement_from = "l"', v='displacement_from = "l"'),
     r"experimental\[1\]\.displacement_from: instrument 'l' already gives the displacement of experimental\[0\]"),
    (dict(w='displacement_from = "l"', element='element = "w"', scale="scale = 0.0"),
     r"instrument\[0\]\.scale: must not be zero"),
    (dict(w='displacement_from = "l"', element='element = "w"', scale="scale = -1.0"),
     r"experimental\[0\]\.displacement_from: instrument 'l' has scale -1: it would read the element's displacement "
     r"with the opposite sign"),
], ids=["another element's", "two elements", "scale zero", "scale negative"])
def test_an_instrument_that_cannot_be_the_elements_displacement_is_refused(fields, message):
    """An outer loop would drive the element's actuator by what the instrument reads: on another
    element, shared, or reading nothing (scale 0: the loop winds the command up to a limit)."""
    text = TWO.format(**{"w": "", "v": "", "element": "", "scale": "", **fields})
    with pytest.raises(ConfigError, match=r"two\.toml: " + message):
        parse_structure(text, "two.toml")
    assert parse_structure(TWO.format(w="", v="", element='element = "w"', scale="scale = -1.0"),
                           "two.toml").instruments[0].scale == -1.0  # only read and recorded: fine


@pytest.mark.parametrize("arguments, message", [
    (dict(instruments=(Instrument("l", "laser", "x"),)), r"instrument\[0\]\.kind: unknown instrument 'laser'"),
    (dict(instruments=(Instrument("l", ["lvdt"], "x"),)), r"instrument\[0\]\.kind: unknown instrument \['lvdt'\]"),
    (dict(instruments=(Instrument("l", "lvdt", "y"),)), r"instrument\[0\]\.element: no experimental element 'y'"),
    (dict(instruments=(Instrument("l", "lvdt", "x", scale=float("nan")),)), r"instrument\[0\]\.scale: must be finite"),
    (dict(displacement_from="l"), r"experimental\[0\]\.displacement_from: no instrument 'l'; instruments: none"),
], ids=["kind", "kind not a string", "element", "scale", "displacement_from"])
def test_a_structure_built_in_code_gets_the_instrument_checks(arguments, message):
    """As a file would be refused: not a KeyError later, nor an element left silently on its
    actuator's transducer."""
    element = ExperimentalElement("x", 0, {"kind": "linear", "k": 1.0},
                                  displacement_from=arguments.pop("displacement_from", ""))
    with pytest.raises(ConfigError, match=r"structure 's': " + message):
        Structure("s", ("x",), (0.01,), (element,), damping=Damping(0.05, "mass"), dt=0.01, **arguments)


def test_instruments_without_their_daq_are_refused_before_any_actuator_opens(monkeypatch):
    """On a controller's URL, a structure with instruments needs the DAQ module's URL: refused
    before the hardware is opened (no axis enabled), not after."""
    import hsio.api

    opened = []
    monkeypatch.setattr(hsio.api, "open_hardware", lambda *args: opened.append(args) or [])
    structure = parse_structure(WALL.format(source='displacement_from = "lvdt"'), "wall.toml")
    with pytest.raises(ConfigError, match="names instruments; give the DAQ module's URL as the driver option"):
        hsio.open_site(structure, "modbus+tcp://127.0.0.1:1", options={"stroke_mm": 100.0, "force_kN": 50.0})
    assert opened == []


def test_a_refusal_before_any_motion_leaves_a_site_with_instruments_usable_from_rest():
    structure = parse_structure(WALL.format(source='displacement_from = "lvdt"'), "wall.toml")
    too_long = hsio.GroundMotion("long", 0.01, np.zeros(600_000))  # 6000 s: 1.2e6 steps at 0.005 s
    ground = hsio.synthetic_record(duration_s=0.2, dt=structure.dt, pga_g=0.3, seed=1)
    with hsio.open_site(structure, "emulator://") as site:
        with pytest.raises(hsio.HsioError, match="more than the bound"):
            hsio.simulate(structure, too_long, site)
        assert hsio.simulate(structure, ground, site).steps == 40  # from rest: nothing had moved


def test_an_emulated_instrument_on_an_element_with_a_setup_is_refused_before_anything_opens(monkeypatch):
    import hsio.api

    opened = []
    monkeypatch.setattr(hsio.api, "open_hardware", lambda *args: opened.append(args) or [])
    structure = parse_structure(RIG.replace('element = "wall"', 'element = "column"').replace(
        'displacement_from = "lvdt"\nouter_loop = { tolerance_mm = 0.002, max_iterations = 3 }\n', ""), "rig.toml")
    with pytest.raises(ConfigError, match="instrument 'lvdt' reads element 'column', which is loaded through a setup"):
        hsio.open_site(structure, "emulator://")
    structure = parse_structure(RIG.replace('element = "wall"\n', "").replace(
        'displacement_from = "lvdt"\nouter_loop = { tolerance_mm = 0.002, max_iterations = 3 }\n', ""), "rig.toml")
    with pytest.raises(ConfigError, match="instrument 'lvdt' names no element: the emulator has nothing for it to read"):
        hsio.open_site(structure, "emulator://")
    assert opened == []


def test_hsio_run_shows_the_initial_read_back_and_summarises_the_outer_loop(tmp_path):
    from hsio import config as config_mod
    from hsio import runner

    (tmp_path / "wall.toml").write_text(WALL.format(
        source='displacement_from = "lvdt"\nouter_loop = { tolerance_mm = 0.02, max_iterations = 4 }'))
    (tmp_path / "run.toml").write_text('[structure]\nfile = "wall.toml"\n[record]\nsynthetic_duration_s = 0.5\n'
                                       '[emulator]\ncompliance_mm_per_kN = 0.05\n[output]\nplots = false\n')
    said = []
    summary = runner.run(config_mod.load(tmp_path / "run.toml"), tmp_path / "out", notify=said.append)
    loops = summary["outer_loop_iterations"]
    assert 0.5 < loops["mean"] <= loops["max"] <= 4
    readback = next(line for line in said if line.startswith("initial read-back:"))
    assert readback.splitlines()[-1].split() == ["lvdt", "0.0000", "mm"]  # the specimen at rest


@pytest.mark.parametrize("command", [["check"], ["run"], ["run", "--monitor", "--monitor-port", "0"]])
def test_an_emulated_instrument_naming_no_element_is_refused_before_any_folder(tmp_path, command):
    """`hsio check` refuses it as `hsio run` does (exit 2, the instrument named), and `hsio run`
    refuses it before the run folder (or the monitor's) exists."""
    from click.testing import CliRunner

    from hsio.cli import main

    (tmp_path / "wall.toml").write_text(WALL.format(source="").replace('element = "wall"\n', ""))
    (tmp_path / "run.toml").write_text('[structure]\nfile = "wall.toml"\n[record]\nsynthetic_duration_s = 0.2\n'
                                       '[output]\nplots = false\n[safety]\nkeys = false\n')
    args = [*command, str(tmp_path / "run.toml")] + (["--out", str(tmp_path / "out")] if command[0] == "run" else [])
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 2, result.output
    assert "instrument 'lvdt' names no element" in result.output and "Traceback" not in result.output
    assert not (tmp_path / "out").exists()


STIFF_WALL = """
[structure]
name = "stiff_wall"
dt = 0.005
[[dof]]
name = "x"
mass = 0.0395785
[damping]
kind = "stiffness"
zeta = 0.05
modes = [1]
[[experimental]]
name = "w"
dof = "x"
{actuators}
displacement_from = "lv"
{outer_loop}
model = {{ kind = "linear", k = 100.0 }}
[[instrument]]
name = "lv"
kind = "lvdt"
element = "w"
"""


@pytest.mark.parametrize("method", ["implicit_dc", "alpha_os"])
def test_an_instrument_read_as_the_trial_ends_pairs_with_the_force_measured_then(method):
    """A stiff linear wall (100 kN/mm, 8 Hz) read by an exact LVDT, at TR 10 ramp-hold: the rod is
    still settling in the dwell (20 ms lag), so the load cell's average over the last periods is
    the force of earlier positions than the LVDT's one reading at the trial's end; paired with that
    reading, it makes the wall look stiffer or softer than it is by k times the settling (7.0 % off
    NS in implicit DC, 1.2 % in alpha_os). Paired with the force of the last period, HS is NS."""
    structure = parse_structure(STIFF_WALL.format(actuators='actuator = "A1"', outer_loop=""), "stiff_wall.toml")
    ground = hsio.synthetic_record(duration_s=2.0, dt=structure.dt, pga_g=0.15, seed=11)
    ns = hsio.run_numerical(structure, ground)
    implicit = method != "alpha_os"
    with hsio.open_site(structure, "emulator://", test_rate=10, hold_fraction=0.5,
                        estimator=SecantEstimator("average", 16, 0.1) if implicit else None) as site:
        hs = hsio.simulate(structure, ground, site,
                           integrator=hsio.make_integrator(structure, method) if implicit else None)
    assert max_error_pct(hs.u, ns.u)[0] < 0.1


@pytest.mark.parametrize("method, actuators", [
    pytest.param("implicit_dc", 'actuator = "A1"', id="one actuator"),
    pytest.param("alpha_os", 'actuators = ["east", "west"]\nsetup = { kind = "parallel", ratios = [1.0, 1.0] }',
                 id="parallel"),
])
def test_the_force_of_the_last_period_is_the_one_after_the_outer_loop_s_last_correction(method, actuators):
    """The same wall behind a load train of 0.002 mm/kN (the LVDT reads 5/6 of the rod's move) with
    an outer loop on the LVDT, on one actuator and on two side by side (``parallel``: the basic
    force from both actuators' last periods): the reading after the loop's last correction pairs
    with the force of that trial's last period, and HS is NS (the averaged force: 3.3 % off in
    implicit DC, 0.71 % through the parallel setup in alpha_os)."""
    outer = "outer_loop = { tolerance_mm = 0.05, max_iterations = 4 }"
    structure = parse_structure(STIFF_WALL.format(actuators=actuators, outer_loop=outer), "stiff_wall.toml")
    ground = hsio.synthetic_record(duration_s=1.0, dt=structure.dt, pga_g=0.15, seed=11)
    ns = hsio.run_numerical(structure, ground)
    implicit = method != "alpha_os"
    with hsio.open_site(structure, "emulator://", test_rate=10, hold_fraction=0.5,
                        options={"compliance_mm_per_kN": 0.002},
                        estimator=SecantEstimator("average", 16, 0.1) if implicit else None) as site:
        hs = hsio.simulate(structure, ground, site,
                           integrator=hsio.make_integrator(structure, method) if implicit else None)
    assert max(n for _, n, _ in hs.instrument_log) >= 1  # the loop corrected
    assert max_error_pct(hs.u, ns.u)[0] < 0.1
