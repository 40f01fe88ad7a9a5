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
