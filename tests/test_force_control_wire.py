"""Force and mixed control over the wire: the drivers switch modes and command forces."""

import itertools

import numpy as np

from hsio.drivers import modbus_map
from hsio.commands.emulate import bank_from_config
from hsio.emulators.canopen import CanopenEmulator
from hsio.emulators.modbus import ModbusEmulator
from wire import QUIET_SENSORS, max_abs_diff, run

MIXED = """
[structure]
name = "structure_I"
[record]
duration_s = 1.5
pga_g = 1.0
[integrator]
method = "mixed"
switch_rule = "initial_stiffness"  # K^EI-based thresholds: the wall switches to FC and back
[test]
rate = 5.0
[output]
plots = false
"""
_channels = itertools.count()


def mixed_config(tmp_path):
    path = tmp_path / "mixed.toml"
    path.write_text(MIXED + QUIET_SENSORS)
    return path


def check_same_run(local, a, wire, b, tolerance_mm):
    assert wire["steps"] == local["steps"]
    assert local["switches"] > 0, "the record must make the wall switch to FC and back"
    assert wire["switches"] == local["switches"]
    assert list(a.steps["mode_wall"]) == list(b.steps["mode_wall"])
    assert max_abs_diff(a, b) <= tolerance_mm


def test_mixed_run_over_modbus_tcp_equals_in_process(tmp_path):
    cfg = mixed_config(tmp_path)
    emu = ModbusEmulator(bank_from_config(cfg, lockstep=True), modbus_map.load()).start()
    try:
        local, a = run(cfg, tmp_path / "local")
        wire, b = run(cfg, tmp_path / "wire", url=emu.url)
    finally:
        emu.stop()
    check_same_run(local, a, wire, b, 1e-4 * max(local["peak_displacement_mm"]))


def test_mixed_run_over_canopen_equals_in_process_within_counts(tmp_path):
    cfg = mixed_config(tmp_path)
    emu = CanopenEmulator(bank_from_config(cfg, lockstep=True), f"hsio-fc-{next(_channels)}").start()
    try:
        local, a = run(cfg, tmp_path / "local")
        wire, b = run(cfg, tmp_path / "wire", url=emu.url)
    finally:
        emu.stop()
    # Forces cross as int16 per mille of 10 kN (0.01 kN), positions as 1 um counts.
    check_same_run(local, a, wire, b, 0.01 * max(local["peak_displacement_mm"]))
    assert np.max(np.abs(b.steps["force_wall"])) > 1.0
