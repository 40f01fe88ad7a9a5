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
