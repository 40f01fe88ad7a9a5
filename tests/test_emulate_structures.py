"""`hsio emulate` serves every actuator a structure's run opens: one axis per element and one per
static preload, in that order; a structure whose elements are loaded through setups (actuators
sharing a specimen) is refused by name rather than served as independent axes."""

import pytest

import hsio
from hsio.commands.emulate import bank_from_config
from hsio.drivers import modbus_map
from hsio.emulators.modbus import ModbusEmulator
from hsio.errors import ConfigError


def test_a_preloaded_column_runs_over_modbus_with_its_preload_held(tmp_path):
    cfg = tmp_path / "run.toml"
    cfg.write_text('[structure]\nname = "preloaded_column"\n')
    bank = bank_from_config(str(cfg), lockstep=True, watchdog_s=0)
    assert bank.names == ["lateral", "axial"]
    structure = hsio.load_structure("preloaded_column")
    ground = hsio.synthetic_record(duration_s=0.3, dt=structure.dt, pga_g=0.3, seed=2)
    with ModbusEmulator(bank, modbus_map.load()) as emu:
        with hsio.open_site(structure, emu.url, test_rate=10,
                            options={"stroke_mm": 254.0, "force_kN": 250.0}) as site:
            hs = hsio.simulate(structure, ground, site)
    assert hs.steps == 30 and hs.static_hold_error[0] < 0.01
    assert [p for p, *_ in hs.static_log][-1] == "ramp_off"


def test_a_structure_with_setups_is_refused_naming_its_elements(tmp_path):
    cfg = tmp_path / "run.toml"
    cfg.write_text('[structure]\nname = "column_two_actuators"\n')
    with pytest.raises(ConfigError, match=r"structure 'column_two_actuators': element\(s\) column are loaded through "
                                          r"a setup .*run such a structure on emulator://"):
        bank_from_config(str(cfg), lockstep=True, watchdog_s=0)


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
displacement_from = "lvdt"
model = { kind = "linear", k = 2.6 }
[[instrument]]
name = "lvdt"
kind = "lvdt"
element = "wall"
resolution = 0.01
"""


def test_the_structures_instruments_are_served_on_the_controllers_wire(tmp_path):
    """The pair `hsio emulate modbus run.toml` / `hsio run run.toml` with [driver] instruments at
    the emulator's URL: the run reads the LVDT through the DAQ map on the same device."""
    from hsio.commands.emulate import _with_instruments

    (tmp_path / "wall.toml").write_text(WALL)
    cfg = tmp_path / "run.toml"
    cfg.write_text('[structure]\nfile = "wall.toml"\n')
    bank = bank_from_config(str(cfg), lockstep=True, watchdog_s=0)
    structure = hsio.load_structure(tmp_path / "wall.toml")
    ground = hsio.synthetic_record(duration_s=0.5, dt=structure.dt, pga_g=0.3, seed=2)
    ns = hsio.run_numerical(structure, ground)
    with _with_instruments(ModbusEmulator(bank, modbus_map.load()), str(cfg)) as emu:
        options = {"stroke_mm": 254.0, "force_kN": 250.0, "instruments": emu.url}
        with hsio.open_site(structure, emu.url, test_rate=10, options=options) as site:
            hs = hsio.simulate(structure, ground, site)
    readings = [r["lvdt"] for _, _, r in hs.instrument_log]
    assert hs.measured_displacement[1:, 0].tolist() == readings  # the LVDT over the wire, 0.01 mm a count
    assert hsio.max_error_pct(hs, ns)[0] < 2.0


def test_more_instruments_than_the_daq_map_has_inputs_are_refused_by_the_emulator(tmp_path):
    from hsio.commands.emulate import _with_instruments

    many = "".join(f'[[instrument]]\nname = "l{k}"\nkind = "lvdt"\nelement = "wall"\n' for k in range(11))
    (tmp_path / "wall.toml").write_text(WALL + many)
    cfg = tmp_path / "run.toml"
    cfg.write_text('[structure]\nfile = "wall.toml"\n')
    bank = bank_from_config(str(cfg), lockstep=True, watchdog_s=0)
    with pytest.raises(ValueError, match="DAQ map .hsio-daq. has 8 inputs for 12 instruments"):
        _with_instruments(ModbusEmulator(bank, modbus_map.load()), str(cfg))


def test_an_instrument_beyond_its_inputs_full_scale_is_named_not_a_device_failure():
    """The default DAQ map's int16 inputs with scale 100 hold +/-327.67: a strain gauge of 12.5
    microstrain per kN is beyond at 26 kN. The emulated converter saturates, as a real one does,
    and the driver refuses the saturated reading by name (the wire stays healthy)."""
    from hsio.drivers.modbus_daq import ModbusDAQ, load_daq_map
    from hsio.emulators.bank import ControllerBank
    from hsio.emulators.local import EmulatedInstruments
    from hsio.emulators.servo import make_controllers
    from hsio.errors import ImplausibleMeasurementError
    from hsio.structure_file import parse_structure

    gauges = '[[instrument]]\nname = "lc"\nkind = "load_cell"\nelement = "wall"\n' \
             '[[instrument]]\nname = "sg"\nkind = "strain_gauge"\nelement = "wall"\nscale = 12.5\n'
    structure = parse_structure(WALL + gauges, "wall.toml")
    (controller,) = make_controllers(structure.experimental, {"noise_mm": 0.0, "force_noise_kN": 0.0,
                                                              "resolution_mm": 0.0})
    daq = EmulatedInstruments(structure.instruments, {"wall": controller})
    with ModbusEmulator(ControllerBank([controller], ["wall"], lockstep=True, watchdog_s=0), modbus_map.load()) as emu:
        emu.context.add_instruments(daq, load_daq_map())
        reader = ModbusDAQ(emu.url, structure.instruments)
        try:
            controller.set_command(8.0)  # 20.8 kN: 260 microstrain, within the input
            controller.advance(800)
            assert reader.read()["sg"] == pytest.approx(12.5 * 2.6 * 8.0, abs=0.01)
            controller.set_command(12.0)  # 31.2 kN: 390 microstrain, beyond +/-327.67
            controller.advance(800)
            with pytest.raises(ImplausibleMeasurementError, match=r"instrument 'sg' on input 'ai2' reads 327\.67 "
                                                                  r"microstrain, the full scale of its int16 register"):
                reader.read()
            controller.set_command(8.0)
            controller.advance(800)
            assert reader.read()["lc"] == pytest.approx(20.8, abs=0.01)  # the module still answers
        finally:
            reader.close()


def test_an_unsigned_input_reading_zero_is_a_reading_not_a_saturated_converter():
    """A uint16 input holds 0..655.35 at scale 100: its zero is where the instrument stands at
    rest, read as 0.0, while its top (655.35) is the converter's full scale, refused by name."""
    from hsio.drivers.modbus_daq import ModbusDAQ, daq_map_from_dict
    from hsio.emulators.bank import ControllerBank
    from hsio.emulators.local import EmulatedInstruments
    from hsio.emulators.servo import make_controllers
    from hsio.errors import ImplausibleMeasurementError
    from hsio.structure_file import parse_structure

    gauge = '[[instrument]]\nname = "sg"\nkind = "strain_gauge"\nelement = "wall"\nscale = 30.0\n'
    structure = parse_structure(WALL + gauge, "wall.toml")
    (controller,) = make_controllers(structure.experimental, {"noise_mm": 0.0, "force_noise_kN": 0.0,
                                                              "resolution_mm": 0.0})
    daq_map = daq_map_from_dict({"map": {"name": "unsigned"},
                                 "inputs": {"ai0": {"address": 600, "type": "uint16", "scale": 100.0},
                                            "ai1": {"address": 601, "type": "uint16", "scale": 100.0}}})
    daq = EmulatedInstruments(structure.instruments, {"wall": controller})
    with ModbusEmulator(ControllerBank([controller], ["wall"], lockstep=True, watchdog_s=0), modbus_map.load()) as emu:
        emu.context.add_instruments(daq, daq_map)
        reader = ModbusDAQ(emu.url, structure.instruments, daq_map)
        try:
            assert reader.read() == {"lvdt": 0.0, "sg": 0.0}  # at rest
            controller.set_command(12.0)  # 31.2 kN: 936 microstrain, beyond 655.35
            controller.advance(800)
            with pytest.raises(ImplausibleMeasurementError, match=r"instrument 'sg' on input 'ai1' reads 655\.35"):
                reader.read()
        finally:
            reader.close()
