"""A DAQ module's register map with gaps between its inputs (cards at other addresses, other types
and word orders): each read covers inputs' registers only, so a module that refuses an address it
does not map (as hsio's emulator does, with exception 2) is read all the same (docs/setups.md)."""

from importlib import resources

import pytest

from hsio.drivers import modbus_map
from hsio.drivers.modbus_daq import ModbusDAQ, daq_map_from_dict
from hsio.emulators.bank import ControllerBank
from hsio.emulators.local import EmulatedInstruments
from hsio.emulators.modbus import ModbusEmulator
from hsio.emulators.servo import make_controllers
from hsio.structure_file import parse_structure

WALL = (resources.files("hsio") / "library" / "structure_I.toml").read_text()
INSTRUMENTS = """
[[instrument]]
name = "lvdt"
kind = "lvdt"
element = "wall"
[[instrument]]
name = "load_cell"
kind = "load_cell"
element = "wall"
[[instrument]]
name = "gauge"
kind = "strain_gauge"
element = "wall"
scale = -40.0
"""
GAPPED = {"map": {"word_order": "little"}, "inputs": {
    "card1_ai0": {"address": 700, "type": "int32", "scale": 1000.0},
    "card1_ai1": {"address": 702, "type": "int16", "scale": 10.0},
    "card2_ai0": {"address": 720, "type": "float32", "scale": -1.0}}}


def test_spans_join_adjacent_inputs_only():
    daq_map = daq_map_from_dict(GAPPED, "gapped.toml")
    assert daq_map.spans(3) == [(700, 3), (720, 2)]
    assert daq_map.spans(2) == [(700, 3)]


def test_a_map_with_gaps_between_its_inputs_is_read_through_the_emulator():
    structure = parse_structure(WALL + INSTRUMENTS, "wall.toml")
    order = {"lvdt": "card1_ai0", "load_cell": "card2_ai0", "gauge": "card1_ai1"}  # instruments take inputs in order
    inputs = {name: GAPPED["inputs"][order[name]] for name in ("lvdt", "load_cell", "gauge")}
    daq_map = daq_map_from_dict({"map": GAPPED["map"], "inputs": inputs}, "gapped.toml")
    (controller,) = make_controllers(structure.experimental, {"noise_mm": 0.0, "force_noise_kN": 0.0,
                                                              "resolution_mm": 0.0, "compliance_mm_per_kN": 0.05})
    controller.set_command(-9.0)
    controller.advance(400)
    bank = ControllerBank([controller], ["wall"], lockstep=True, watchdog_s=0)
    with ModbusEmulator(bank, modbus_map.load()) as emu:
        emu.context.add_instruments(EmulatedInstruments(structure.instruments, {"wall": controller}), daq_map)
        reader = ModbusDAQ(emu.url, structure.instruments, daq_map)
        try:
            values = reader.read()
        finally:
            reader.close()
    assert values["lvdt"] == pytest.approx(controller.d_spec, abs=0.0006)  # int32 at 0.001 mm a count
    assert values["load_cell"] == pytest.approx(controller.force, rel=1e-6)  # float32
    assert values["gauge"] == pytest.approx(-40.0 * controller.force, abs=0.06)  # int16 at 0.1 a count
