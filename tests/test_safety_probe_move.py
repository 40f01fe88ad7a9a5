"""`hsio probe --move` goes through the checks of a run (docs/safety.md section 3): the velocity
limit and the interlocks, not only the stroke. A refusal or a trip holds the axis and exits 2."""

from __future__ import annotations

import json

import numpy as np
from click.testing import CliRunner

from hsio.commands.emulate import bank_from_config
from hsio.commands.probe import _ramp, probe
from hsio.drivers import modbus_map
from hsio.emulators.modbus import ModbusEmulator
from wire import QUIET_SENSORS, write_config


def probe_move(tmp_path, *args, emulator: str = ""):
    cfg = write_config(tmp_path, extra=QUIET_SENSORS + emulator)
    emu = ModbusEmulator(bank_from_config(cfg, lockstep=True), modbus_map.load()).start()
    try:
        result = CliRunner().invoke(probe, [emu.url, "--move", "--json", "--requests", "5", *args])
        holding = [c.holding for c in emu.bank.controllers]
        peak = max(abs(c.d_rod) for c in emu.bank.controllers)
    finally:
        emu.stop()
    return result, json.loads(result.stdout), holding, peak


def test_probe_move_within_the_limits_ramps_its_step_at_the_velocity_limit(tmp_path):
    result, report, holding, _ = probe_move(tmp_path, "--sine-hz", "2.0")
    assert result.exit_code == 0, result.output
    move = report["move"]
    assert 0 < move["step_ramp_s"] < 0.01 and move["rise_time_s"] > 0 and move["rms_tracking_error_mm"] < 0.5
    assert all(holding)
    ramp = _ramp(0.0, 10.0, 450.0, 1024.0)
    assert ramp[-1] == 10.0 and np.max(np.diff(np.r_[0.0, ramp])) * 1024.0 <= 450.0 + 1e-9


def test_probe_move_beyond_the_velocity_limit_is_refused_and_holds(tmp_path):
    # 5 mm at 20 Hz: 2 pi 20 x 5 = 628 mm/s, beyond the 500 mm/s limit
    result, report, holding, peak = probe_move(tmp_path, "--sine-mm", "5", "--sine-hz", "20")
    assert result.exit_code == 2
    assert "command velocity" in report["error"] and "beyond the limit (500.0 mm/s)" in report["error"]
    assert all(holding) and peak < 5.0  # refused before the sine came near its peak velocity


def test_probe_move_trips_on_an_actuator_that_does_not_follow(tmp_path):
    """A servo that lags by 1000 s: the following-error interlock of a run trips the probe."""
    # |12 sin| stays above the 10 mm following-error threshold for 0.6 s of each 3.3 s period
    result, report, holding, peak = probe_move(tmp_path, "--sine-mm", "12", "--sine-hz", "0.3",
                                               emulator="lag_s = 1000.0\n")
    assert result.exit_code == 2
    assert "interlock (following)" in report["error"] and "does not follow its command" in report["error"]
    assert all(holding)
