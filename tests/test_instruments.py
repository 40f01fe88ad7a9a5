"""External instruments: read every trial and recorded, served over Modbus TCP by the emulator and
read through a register map, and an outer loop that closes on an external LVDT (docs/setups.md)."""

from importlib import resources

import numpy as np
import pytest

import hsio
from hsio.drivers import modbus_map
from hsio.drivers.modbus_daq import ModbusDAQ, daq_map_from_dict, load_daq_map
from hsio.emulators.bank import ControllerBank
from hsio.emulators.local import EmulatedInstruments
from hsio.emulators.modbus import ModbusEmulator
from hsio.emulators.servo import make_controllers
from hsio.errors import ConfigError
from hsio.interfaces import ControlMode
from hsio.recording import Recorder, Run
from hsio.result import max_error_pct
from hsio.structure_file import parse_structure

WALL = (resources.files("hsio") / "library" / "structure_I.toml").read_text()
INSTRUMENTS = """
[[instrument]]
name = "wall_lvdt"
kind = "lvdt"
element = "wall"
resolution = 0.005
[[instrument]]
name = "wall_load_cell"
kind = "load_cell"
element = "wall"
[[instrument]]
name = "wall_gauge"
kind = "strain_gauge"
element = "wall"
scale = 12.5
"""


def with_lvdt(tolerance=0.05, iterations=4):
    text = WALL.replace('[[experimental]]\nname = "wall"', '[[experimental]]\nname = "wall"\n'
                        'displacement_from = "wall_lvdt"\n'
                        f'outer_loop = {{ tolerance_mm = {tolerance}, max_iterations = {iterations} }}')
    return parse_structure(text + INSTRUMENTS, "wall_lvdt.toml")


def test_emulator_serves_instruments_over_modbus_tcp():
    structure = parse_structure(WALL + INSTRUMENTS, "wall.toml")
    (controller,) = make_controllers(structure.experimental, {"noise_mm": 0.0, "force_noise_kN": 0.0, "resolution_mm": 0.0,
                                                              "compliance_mm_per_kN": 0.05})
    controller.set_command(12.0)
    controller.advance(400)
    daq = EmulatedInstruments(structure.instruments, {"wall": controller})
    bank = ControllerBank([controller], ["wall"], lockstep=True, watchdog_s=0)
    with ModbusEmulator(bank, modbus_map.load()) as emu:
        emu.context.add_instruments(daq, load_daq_map())
        reader = ModbusDAQ(emu.url, structure.instruments)
        try:
            assert [c.unit for c in reader.channels] == ["mm", "kN", "microstrain"]
            values = reader.read()
        finally:
            reader.close()
    # the LVDT sees the specimen, short of the rod by the load train's compliance x force
    assert controller.d_rod == pytest.approx(12.0, abs=0.01)
    assert values["wall_lvdt"] == pytest.approx(controller.d_spec, abs=0.0051)
    assert controller.d_rod - values["wall_lvdt"] == pytest.approx(0.05 * controller.force, abs=0.01)
    assert values["wall_load_cell"] == pytest.approx(controller.force, abs=0.051)  # int16, 0.1 kN a count
    assert values["wall_gauge"] == pytest.approx(12.5 * controller.force, rel=1e-6, abs=0.5)


def test_daq_map_errors_name_the_register():
    with pytest.raises(ConfigError, match=r"daq.toml: \[inputs\]: register 'ai0': type"):
        daq_map_from_dict({"inputs": {"ai0": {"address": 600, "type": "int12"}}}, "daq.toml")
    with pytest.raises(ConfigError, match="overlap"):
        daq_map_from_dict({"inputs": {"ai0": {"address": 600, "type": "float32"}, "ai1": {"address": 601}}}, "daq.toml")


@pytest.mark.parametrize("change, where", [
    (lambda t: t.replace('displacement_from = "wall_lvdt"', 'displacement_from = "wall_pot"'),
     "experimental[0].displacement_from"),
    (lambda t: t.replace('displacement_from = "wall_lvdt"', 'displacement_from = "wall_load_cell"'),
     "experimental[0].displacement_from"),
    (lambda t: t.replace('max_iterations = 4', 'max_iterations = 0'), "experimental[0].outer_loop.max_iterations"),
    (lambda t: t.replace('kind = "lvdt"', 'kind = "laser"'), "instrument[0].kind"),
    (lambda t: t.replace('element = "wall"', 'element = "roof"', 1), "instrument[0].element"),
])
def test_instrument_errors_name_the_key(change, where):
    text = WALL.replace('[[experimental]]\nname = "wall"', '[[experimental]]\nname = "wall"\n'
                        'displacement_from = "wall_lvdt"\nouter_loop = { tolerance_mm = 0.05, max_iterations = 4 }')
    with pytest.raises(ConfigError) as info:
        parse_structure(change(text + INSTRUMENTS), "f.toml")
    assert str(info.value).startswith(f"f.toml: {where}"), str(info.value)


@pytest.fixture(scope="module")
def compliant(tmp_path_factory):
    """Structure I on a load train of 0.05 mm/kN: with and without the external LVDT."""
    plain = hsio.load_structure("structure_I")
    ground = hsio.synthetic_record(duration_s=2.5, dt=plain.dt, pga_g=0.3, seed=1)
    ns = hsio.run_numerical(plain, ground)
    runs = {}
    for label, structure, compliance in (("stiff", plain, 0.0), ("compliant", plain, 0.05),
                                         ("lvdt", with_lvdt(), 0.05)):
        recorder = None
        if label == "lvdt":
            path = tmp_path_factory.mktemp("lvdt") / "run.sqlite"
            recorder = Recorder(path, structure.dof_names, structure.experimental_names)
        with hsio.open_site(structure, "emulator://", test_rate=10,
                            options={"compliance_mm_per_kN": compliance}) as site:
            runs[label] = hsio.simulate(structure, ground, site, recorder=recorder)
        if recorder is not None:
            recorder.close()
            runs["path"] = path
    return ns, runs


def test_outer_loop_on_the_lvdt_removes_the_load_train_error(compliant):
    ns, runs = compliant
    stiff = max_error_pct(runs["stiff"].u, ns.u)[0]
    compliant_error = max_error_pct(runs["compliant"].u, ns.u)[0]
    lvdt = max_error_pct(runs["lvdt"].u, ns.u)[0]
    assert compliant_error > 3 * stiff  # the compliance does the damage
    assert lvdt < compliant_error / 3
    assert lvdt < stiff + 0.5  # back to what the stiff load train gives


def test_outer_loop_iterations_bounded_and_recorded(compliant):
    _, runs = compliant
    hs = runs["lvdt"]
    iterations = np.array([n for _, n, _ in hs.instrument_log])
    readings = np.array([r["wall_lvdt"] for _, _, r in hs.instrument_log])
    assert len(iterations) == len(hs.t) - 1 and iterations.max() <= 4 and iterations.mean() > 0.5
    converged = iterations < 4
    # where the loop stopped before its bound, the LVDT reads the target within the tolerance
    assert np.all(np.abs(readings - hs.targets[1:, 0])[converged] <= 0.05 + 1e-9)
    # the element's measured displacement is the LVDT's, not the rod's
    np.testing.assert_allclose(hs.measured_displacement[1:, 0], readings)
    table = Run(runs["path"]).table("instruments")
    np.testing.assert_array_equal(table["iterations"], iterations)
    np.testing.assert_allclose(table["wall_lvdt"], readings)
    assert np.max(np.abs(table["wall_load_cell"])) > 10.0


@pytest.mark.parametrize("reads, target, says, most", [
    (lambda true: 0.0, 1.0, "went from +1.000 to +1.000 mm off the target", 4.0),  # detached: reads its zero for ever
    (lambda true: -true, 0.25, "went from +0.", 7.75),  # the wrong sign: each correction doubles the error
])
def test_an_outer_loop_whose_instrument_does_not_follow_stops_the_run(reads, target, says, most):
    """An outer loop adds the instrument's error to the command at every correction: on an LVDT
    that fell off (or reads with the wrong sign) it would drive the actuator to several times its
    target. The site stops instead (an implausible measurement: the actuators hold), naming the
    instrument and how far the actuator went; a load train's compliance, which the LVDT follows in
    part, does not stop it (test_outer_loop_iterations_bounded_and_recorded)."""
    from hsio.errors import ImplausibleMeasurementError

    structure = with_lvdt(tolerance=0.05, iterations=4)
    with hsio.open_site(structure, "emulator://", test_rate=10,
                        options={"noise_mm": 0.0, "resolution_mm": 0.0, "compliance_mm_per_kN": 0.05}) as site:
        true_reading = site.read_instruments
        site.read_instruments = lambda: {**true_reading(), "wall_lvdt": reads(true_reading()["wall_lvdt"])}
        with pytest.raises(ImplausibleMeasurementError, match="instrument 'wall_lvdt': the outer loop moved actuator "
                                                               "'wall' ") as info:
            site.set_trial(np.array([target]), [ControlMode.DISPLACEMENT])
        assert says in str(info.value) and "does not follow the actuator" in str(info.value)
        moved = float(str(info.value).split("actuator 'wall' ")[1].split(" mm")[0])
        assert 0.9 < abs(moved) <= most  # at most max_iterations corrections, then stopped


def test_an_outer_loop_on_an_instrument_coarser_than_its_tolerance_says_so_when_it_stops():
    """An LVDT whose resolution (0.6 mm) is far coarser than the loop's tolerance (0.05 mm) follows
    its actuator, but the loop chases its steps until it drifts off the target and stops: the
    message names that cause beside a detached instrument, and the tolerance."""
    text = WALL.replace('[[experimental]]\nname = "wall"', '[[experimental]]\nname = "wall"\n'
                        'displacement_from = "lvdt"\nouter_loop = { tolerance_mm = 0.05, max_iterations = 4 }')
    structure = parse_structure(text + '\n[[instrument]]\nname = "lvdt"\nkind = "lvdt"\nelement = "wall"\n'
                                'resolution = 0.6\n', "coarse.toml")
    ground = hsio.synthetic_record(duration_s=0.5, dt=structure.dt, pga_g=0.3, seed=1)
    with hsio.open_site(structure, "emulator://", test_rate=10, options={"preset": "structure_I"}) as site:
        with pytest.raises(hsio.ExperimentStopped, match="instrument 'lvdt': the outer loop moved actuator") as info:
            hsio.simulate(structure, ground, site)
    assert "reads more coarsely than the loop's tolerance of 0.05 mm (noise or resolution" in str(info.value)


@pytest.mark.parametrize("outer_loop", [True, False])
def test_a_record_from_rest_is_refused_on_an_instrument_that_is_not_zeroed(monkeypatch, outer_loop):
    """An LVDT that reads 3 mm at rest where the actuator's transducer reads 0 (not zeroed): from
    rest its offset would be the specimen's displacement at the first step, and an outer loop would
    move the actuator by 3 mm at once. simulate refuses before any command, naming both readings;
    with relative trials (its reading at enabling is its zero) the same run goes."""
    true_value = EmulatedInstruments.value
    monkeypatch.setattr(EmulatedInstruments, "value",
                        lambda self, inst: true_value(self, inst) + (3.0 if inst.name == "wall_lvdt" else 0.0))
    structure = with_lvdt()
    if not outer_loop:
        structure = parse_structure(WALL.replace('[[experimental]]\nname = "wall"', '[[experimental]]\nname = "wall"\n'
                                                 'displacement_from = "wall_lvdt"') + INSTRUMENTS, "wall.toml")
    ground = hsio.synthetic_record(duration_s=0.2, dt=structure.dt, pga_g=0.3, seed=1)
    with hsio.open_site(structure, "emulator://", test_rate=2) as site:
        with pytest.raises(ConfigError, match=r"instrument 'wall_lvdt' reads \+3\.0\d\d mm at rest where actuator "
                                              r"'wall' reads [+-]0\.0\d\d mm .*nothing moved"):
            hsio.simulate(structure, ground, site)
        assert not getattr(site, "moved", False) and site.instrument_log == []
    with hsio.open_site(structure, "emulator://", test_rate=2, relative=True) as site:
        hs = hsio.simulate(structure, ground, site)
    assert hs.steps == 40 and abs(hs.commands[1, 0]) < 0.1  # no jump by the offset at the first step


@pytest.mark.parametrize("noise, resolution, offset", [(0.4, 0.0, 0.0), (0.0, 0.3, 0.3)])
def test_a_zeroed_instrument_coarser_than_the_tolerance_is_not_taken_for_one_not_zeroed(monkeypatch, noise, resolution,
                                                                                        offset):
    """A zeroed string pot whose one reading at enabling is off by its own noise (0.4 mm: the
    emulator's draw reads -0.13 mm) or by a step of its resolution (0.3 mm) is within what the
    instrument can tell: the limit grows by its noise and resolution, and the run from rest goes;
    3 mm more is still refused."""
    true_value = EmulatedInstruments.value
    text = WALL.replace('[[experimental]]\nname = "wall"', '[[experimental]]\nname = "wall"\ndisplacement_from = "pot"')
    structure = parse_structure(text + f'\n[[instrument]]\nname = "pot"\nkind = "string_pot"\nelement = "wall"\n'
                                f'noise = {noise}\nresolution = {resolution}\n', "pot.toml")
    for extra, refused in ((offset, False), (offset + 3.0, True)):
        monkeypatch.setattr(EmulatedInstruments, "value", lambda self, inst, extra=extra: true_value(self, inst) + extra)
        with hsio.open_site(structure, "emulator://", test_rate=2) as site:
            reading = site.readback["pot"]
            if refused:
                with pytest.raises(ConfigError, match="instrument 'pot' reads .* at rest"):
                    site.check_instruments_at_rest()
            else:
                assert abs(reading) > 0.1  # beyond 5 x 0.02 mm: refused on the tolerance alone
                site.check_instruments_at_rest()


@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_a_float_input_that_reads_no_number_is_refused_naming_the_instrument(bad):
    """A float32 input of a broken channel reads NaN (or an infinity): refused as implausible,
    naming the instrument and the input, not passed on as an element's displacement."""
    from hsio.errors import ImplausibleMeasurementError

    text = WALL + "".join(f'[[instrument]]\nname = "i{k}"\nkind = "lvdt"\nelement = "wall"\n' for k in range(7))
    structure = parse_structure(text, "wall.toml")
    (controller,) = make_controllers(structure.experimental, {})
    daq = EmulatedInstruments(structure.instruments, {"wall": controller})
    daq.value = lambda inst: bad if inst.name == "i6" else 1.0  # i6 is on ai6, a float32 input
    bank = ControllerBank([controller], ["wall"], lockstep=True, watchdog_s=0)
    with ModbusEmulator(bank, modbus_map.load()) as emu:
        emu.context.add_instruments(daq, load_daq_map())
        reader = ModbusDAQ(emu.url, structure.instruments)
        try:
            with pytest.raises(ImplausibleMeasurementError, match="instrument 'i6' on input 'ai6' reads .*not a number"):
                reader.read()
        finally:
            reader.close()


def test_inputs_further_apart_than_one_modbus_read_are_read_in_several():
    """One read of holding registers takes at most 125 of them: inputs at 600, 601 and 900 are
    read in two requests (a single one of 301 registers was refused by the Modbus client)."""
    structure = parse_structure(WALL + INSTRUMENTS, "wall.toml")
    daq_map = daq_map_from_dict({"inputs": {
        "ai0": {"address": 600, "type": "int16", "scale": 100.0},
        "ai1": {"address": 900, "type": "float32"},
        "ai2": {"address": 601, "type": "int16", "scale": 10.0}}}, "far.toml")
    assert daq_map.spans(3) == [(600, 2), (900, 2)]
    (controller,) = make_controllers(structure.experimental, {"noise_mm": 0.0, "force_noise_kN": 0.0, "resolution_mm": 0.0})
    controller.set_command(12.0)
    controller.advance(400)
    bank = ControllerBank([controller], ["wall"], lockstep=True, watchdog_s=0)
    with ModbusEmulator(bank, modbus_map.load()) as emu:
        emu.context.add_instruments(EmulatedInstruments(structure.instruments, {"wall": controller}), daq_map)
        reader = ModbusDAQ(emu.url, structure.instruments, daq_map)
        try:
            values = reader.read()
        finally:
            reader.close()
    assert values["wall_lvdt"] == pytest.approx(controller.d_spec, abs=0.0051)
    assert values["wall_load_cell"] == pytest.approx(controller.force, rel=1e-6)  # float32
    assert values["wall_gauge"] == pytest.approx(12.5 * controller.force, abs=0.051)
