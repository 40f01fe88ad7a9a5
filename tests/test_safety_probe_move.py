"""`hsio probe --move` goes through the checks of a run (docs/safety.md section 3): the velocity
limit and the interlocks, not only the stroke. A refusal or a trip exits 2; the axis is held and
the hold read back. Bad settings are refused before anything moves."""

from __future__ import annotations

import json

import click
import numpy as np
import pytest
from click.testing import CliRunner

from hsio.commands.emulate import bank_from_config
from hsio.commands.probe import _ramp, probe
from hsio.drivers import modbus_map
from hsio.emulators.modbus import ModbusEmulator
from hsio.interfaces import Limits
from wire import QUIET_SENSORS, write_config


def invoke_probe(tmp_path, *args, emulator: str = ""):
    """`hsio probe --move` against a lockstep Modbus emulator; the result, the emulator's hold
    flags and where its rods stand at the end (furthest from zero)."""
    cfg = write_config(tmp_path, extra=QUIET_SENSORS + emulator)
    emu = ModbusEmulator(bank_from_config(cfg, lockstep=True), modbus_map.load()).start()
    try:
        result = CliRunner().invoke(probe, [emu.url, "--move", "--requests", "5", *args])
        holding = [c.holding for c in emu.bank.controllers]
        rod = max(abs(c.d_rod) for c in emu.bank.controllers)
    finally:
        emu.stop()
    return result, holding, rod


def probe_move(tmp_path, *args, emulator: str = ""):
    result, holding, rod = invoke_probe(tmp_path, "--json", *args, emulator=emulator)
    return result, json.loads(result.stdout), holding, rod


CONFIRMED = {"confirmed": True, "states": {"axis0": True}, "message": "the actuators hold (confirmed by read-back)"}


def test_probe_move_within_the_limits_ramps_its_step_at_the_velocity_limit(tmp_path):
    result, report, holding, _ = probe_move(tmp_path, "--sine-hz", "2.0")
    assert result.exit_code == 0, result.output
    move = report["move"]
    assert 0 < move["step_ramp_s"] < 0.01 and move["rise_time_s"] > 0 and move["rms_tracking_error_mm"] < 0.5
    assert all(holding) and report["hold"] == CONFIRMED
    ramp = _ramp(0.0, 10.0, 450.0, 1024.0)
    assert ramp[-1] == 10.0 and np.max(np.diff(np.r_[0.0, ramp])) * 1024.0 <= 450.0 + 1e-9


def test_probe_move_comes_back_from_a_step_at_a_low_velocity_limit(tmp_path):
    """20 mm/s: the 6 mm step ramps over 6 / 18 s, and so does the way back (a fixed 0.25 s
    return, 24 mm/s, would be refused with the axis left 6 mm away)."""
    result, report, holding, rod = probe_move(tmp_path, "--step-mm", "6", "--sine-mm", "0.5", "--sine-hz", "2",
                                              "--option", "velocity_mm_s=20", emulator="velocity_limit_mm_s = 20.0\n")
    assert result.exit_code == 0, report.get("error")
    assert report["move"]["step_ramp_s"] == pytest.approx(6 / 18, abs=2 / 1024)
    assert rod < 0.01 and all(holding) and report["hold"] == CONFIRMED


def test_probe_move_text_reports_the_ramp_and_the_hold(tmp_path):
    result, _, _ = invoke_probe(tmp_path, "--sine-hz", "2.0")  # 1 mm at 450 mm/s: 3 samples at 1024 Hz
    assert result.exit_code == 0, result.output
    assert "1 mm, ramped over 2.9 ms" in result.stdout and "ramp included" in result.stdout
    assert "hold       the actuators hold (confirmed by read-back)" in result.stdout


def test_probe_move_with_a_sine_beyond_the_velocity_limit_is_refused_before_moving(tmp_path):
    # 5 mm at 20 Hz: 2 pi 20 x 5 = 628 mm/s, beyond the 500 mm/s limit
    result, report, holding, rod = probe_move(tmp_path, "--sine-mm", "5", "--sine-hz", "20")
    assert result.exit_code == 2
    assert report["error"] == ("--sine-mm 5 at --sine-hz 20: peak velocity 2 pi f A = 628.3 mm/s is beyond the "
                               "velocity limit (500.0 mm/s); refused, nothing moved (at 20 Hz the amplitude may be "
                               "up to 3.979 mm)")
    assert "move" not in report and rod < 1e-9
    assert all(holding) and report["hold"] == CONFIRMED


@pytest.mark.parametrize("args, option", [
    (["--sine-hz", "0"], "--sine-hz"), (["--sine-hz", "-1"], "--sine-hz"), (["--sine-mm", "0"], "--sine-mm"),
    (["--sine-mm", "13"], "--sine-mm"), (["--step-mm", "0"], "--step-mm"), (["--step-mm", "-13"], "--step-mm"),
    (["--sine-hz", "nan"], "--sine-hz"), (["--sine-mm", "inf"], "--sine-mm"), (["--step-mm", "nan"], "--step-mm"),
])
def test_probe_move_bad_settings_are_refused_naming_the_option(tmp_path, args, option):
    """Within 5 % of the 254 mm stroke (12.7 mm); a frequency > 0."""
    result, holding, rod = invoke_probe(tmp_path, *args)
    assert result.exit_code == 2 and isinstance(result.exception, SystemExit), result.output
    assert f"Invalid value for '{option}'" in result.stderr or f"Invalid value for {option}" in result.stderr, \
        result.stderr
    assert rod < 1e-9 and all(holding)


@pytest.mark.parametrize("hz, why", [("1e-9", "2/f = 2e+09 s, beyond 40 s"), ("0.049", "2/f = 40.82 s, beyond 40 s"),
                                     ("51", "beyond 50 Hz")])
def test_probe_move_sine_frequency_outside_its_range_is_refused_before_anything_opens(tmp_path, hz, why):
    """The sine lasts two periods, at most 40 s (0.05 Hz); at most 50 Hz (20 commands a period at
    1024 Hz). A 1e-9 Hz sine would last 63 years and take terabytes of commands."""
    result, holding, rod = invoke_probe(tmp_path, "--sine-hz", hz)
    assert result.exit_code == 2 and isinstance(result.exception, SystemExit), result.output
    assert "Invalid value for '--sine-hz'" in result.stderr and "allowed 0.05 to 50 Hz" in result.stderr, result.stderr
    assert why in result.stderr and "identity" not in result.stdout  # refused before connecting
    assert rod < 1e-9 and all(holding)


def test_probe_move_step_whose_ramp_would_outlast_its_bound_is_refused_before_moving(tmp_path):
    """At a velocity limit of 1e-9 mm/s the 1 mm step would ramp for 35 years: refused, naming
    --step-mm and what this controller allows (0.9 x 1e-9 mm/s x 10 s)."""
    result, holding, rod = invoke_probe(tmp_path, "--option", "velocity_mm_s=1e-9", "--sine-mm", "1e-12",
                                        "--sine-hz", "0.1")
    assert result.exit_code == 2 and isinstance(result.exception, SystemExit), result.output
    assert "Invalid value for --step-mm: 1 mm: must be non-zero and within +/-9e-09 mm" in result.stderr, result.stderr
    assert "for at most 10 s" in result.stderr
    assert "refused before anything moved; the actuators hold (confirmed by read-back)" in result.stderr
    assert rod < 1e-9 and all(holding)


def test_check_move_bounds_the_move_from_where_the_axis_stands():
    """From 126 mm of a +/-127 mm stroke a 2 mm step or a 1.5 mm sine would leave the stroke part
    way through: refused before anything moves, naming the range allowed from there."""
    from hsio.commands.probe import MOVE_MAX_S, SINE_MAX_S, check_move

    limits = Limits()
    check_move(limits, 0.0, 2.0, 1.5, 0.5)
    with pytest.raises(click.BadParameter, match=r"step would end at 128.000 mm.*allowed here -12.7 to 1 mm"):
        check_move(limits, 126.0, 2.0, 0.5, 0.5)
    check_move(limits, 126.0, -2.0, 0.5, 0.5)
    with pytest.raises(click.BadParameter, match=r"allowed here up to 1 mm") as refused:
        check_move(limits, 126.0, -2.0, 1.5, 0.5)
    assert refused.value.param_hint == "--sine-mm"
    with pytest.raises(click.BadParameter, match=r"allowed 0.05 to 50 Hz"):
        check_move(limits, 0.0, 1.0, 1.0, 1e-9)
    assert SINE_MAX_S == 40.0 and MOVE_MAX_S == pytest.approx(60.15)


def test_probe_move_trips_on_an_actuator_that_does_not_follow(tmp_path):
    """A servo that lags by 1000 s: the following-error interlock of a run trips the probe."""
    # |12 sin| stays above the 10 mm following-error threshold for 0.6 s of each 3.3 s period
    result, report, holding, _ = probe_move(tmp_path, "--sine-mm", "12", "--sine-hz", "0.3",
                                            emulator="lag_s = 1000.0\n")
    assert result.exit_code == 2
    assert "interlock (following)" in report["error"] and "does not follow its command" in report["error"]
    assert all(holding) and report["hold"] == CONFIRMED


def probe_config(tmp_path, text: str):
    path = tmp_path / "lab.toml"
    path.write_text(text)
    return str(path)


def test_probe_move_uses_the_interlocks_and_driver_options_of_a_run_configuration(tmp_path):
    """The default following-error threshold (10 mm) lets a 1 mm step through; the lab's own
    (0.05 mm, no grace time) trips on the same step's lag, and its [driver] velocity limit sets the
    ramp. The DAQ module's keys of [driver] are not the controller's and are left out."""
    result, report, _, _ = probe_move(tmp_path, "--sine-hz", "2.0")
    assert result.exit_code == 0, report.get("error")
    strict = probe_config(tmp_path, "[safety]\nfollowing_error_mm = 0.05\nfollowing_time_s = 0.0\n")
    result, report, holding, _ = probe_move(tmp_path, "--sine-hz", "2.0", "--config", strict)
    assert result.exit_code == 2, report
    assert "interlock (following)" in report["error"] and report["interlocks"] == "on"
    assert all(holding) and report["hold"] == CONFIRMED

    slow = probe_config(tmp_path, '[driver]\nvelocity_mm_s = 20.0\ninstruments = "modbus+tcp://127.0.0.1:1"\n')
    result, report, holding, rod = probe_move(tmp_path, "--step-mm", "6", "--sine-mm", "0.5", "--sine-hz", "2",
                                              "--config", slow, emulator="velocity_limit_mm_s = 20.0\n")
    assert result.exit_code == 0, report.get("error")
    assert report["move"]["step_ramp_s"] == pytest.approx(6 / 18, abs=2 / 1024)
    # --option overrides the configuration's [driver]: 30 mm/s ramps the step at 27 mm/s
    result, report, _, _ = probe_move(tmp_path, "--step-mm", "6", "--sine-mm", "0.5", "--sine-hz", "2",
                                      "--config", slow, "--option", "velocity_mm_s=30",
                                      emulator="velocity_limit_mm_s = 30.0\n")
    assert result.exit_code == 0, report.get("error")
    assert report["move"]["step_ramp_s"] == pytest.approx(6 / 27, abs=2 / 1024)


def test_probe_with_interlocks_off_in_its_configuration_says_so(tmp_path):
    off = probe_config(tmp_path, "[safety]\ninterlocks = false\n")
    result, holding, _ = invoke_probe(tmp_path, "--sine-hz", "2.0", "--config", off)
    assert result.exit_code == 0, result.output
    assert "interlocks off ([safety] interlocks = false)" in result.stdout
    assert all(holding)


@pytest.mark.parametrize("text, fragment", [("[safety]\nfollowing_error_mm = -1.0\n", "following_error_mm"),
                                            ("[safety\n", "malformed TOML"), (None, "cannot read"),
                                            ('[hardware]\nurl = "canopen+virtual://bus?node=1"\n', "is not a modbus")])
def test_probe_with_a_bad_configuration_is_refused_before_connecting(tmp_path, text, fragment):
    path = probe_config(tmp_path, text) if text is not None else str(tmp_path / "missing.toml")
    result, holding, rod = invoke_probe(tmp_path, "--config", path)
    assert result.exit_code == 2 and isinstance(result.exception, SystemExit), result.output
    assert "Invalid value for --config" in result.stderr and fragment in result.stderr, result.stderr
    assert rod < 1e-9 and all(holding)


def test_a_driver_table_with_the_daq_modules_keys_opens_the_controller(tmp_path):
    """`instruments` and `instrument_map` of [driver] name the external instruments' DAQ module
    (docs/setups.md): the actuator driver, which refuses keys it does not know, never sees them."""
    from hsio import api
    from hsio.structures import get_structure

    cfg = write_config(tmp_path, extra=QUIET_SENSORS)
    emu = ModbusEmulator(bank_from_config(cfg, lockstep=True), modbus_map.load()).start()
    try:
        options = {"instruments": "modbus+tcp://127.0.0.1:1", "instrument_map": "daq.toml"}
        with api.open_site(get_structure("validation"), emu.url, options=options) as site:
            assert [a.name for a in site.loop.actuators] == ["C1", "C2"]
    finally:
        emu.stop()


def test_probe_move_enables_the_axis_only_after_the_latency_measurement(tmp_path):
    """The latency measurement only reads; an axis enabled during it would see no command for as
    long as it lasts (200 requests of 9 ms over RTU at 9600 baud: 1.8 s), and a host watchdog
    shorter than that would latch before the move began. Here the watchdog is 30 ms and the
    reads last longer: the move must still run, and the axis hold at its end."""
    cfg = write_config(tmp_path, extra=QUIET_SENSORS)
    emu = ModbusEmulator(bank_from_config(cfg, lockstep=True, watchdog_s=0.03), modbus_map.load()).start()
    try:
        result = CliRunner().invoke(probe, [emu.url, "--move", "--json", "--requests", "400", "--sine-hz", "2.0"])
        report = json.loads(result.stdout)
        holding = [c.holding for c in emu.bank.controllers]
    finally:
        emu.stop()
    assert result.exit_code == 0, (result.output, report.get("error"))
    assert report["latency"]["requests"] == 400 and report["latency"]["median_ms"] * 400 > 30
    assert "error" not in report and report["move"]["rms_tracking_error_mm"] < 0.5
    assert report["axes"][0]["flags"]["enabled"] is False  # the state is read before anything is enabled
    assert report["hold"] == CONFIRMED and all(holding)


def test_probe_move_with_several_axes_in_real_time_commands_every_axis(tmp_path):
    """In real time a link sends once every axis has its command: with --axes 2 the other axis
    is commanded where it stood, every period, so axis 0's step and sine go out (and the host
    watchdog is fed); both axes hold at the end."""
    cfg = write_config(tmp_path, extra=QUIET_SENSORS, clock="realtime")
    emu = ModbusEmulator(bank_from_config(cfg, lockstep=False, watchdog_s=0.5), modbus_map.load()).start()
    try:
        result = CliRunner().invoke(probe, [emu.url, "--move", "--json", "--axes", "2", "--requests", "5",
                                            "--sine-hz", "10", "--step-mm", "0.5"])
        report = json.loads(result.stdout)
        holding = [c.holding for c in emu.bank.controllers]
        rods = [c.d_rod for c in emu.bank.controllers]
    finally:
        emu.stop()
    assert result.exit_code == 0, (result.output, report.get("error"))
    move = report["move"]
    # A first-order lag tau = 20 ms on a 1 mm sine at 10 Hz: error amplitude w tau / sqrt(1 + (w tau)^2)
    # = 0.78 mm, RMS 0.55 mm (axis 0's commands did go out, at the controller's rate).
    w_tau = 2 * np.pi * 10 * 0.020
    assert move["rms_tracking_error_mm"] == pytest.approx(w_tau / np.sqrt(1 + w_tau**2) / np.sqrt(2), rel=0.2)
    assert move["rise_time_s"] > 0
    assert report["hold"]["confirmed"] and all(holding)
    assert abs(rods[1]) < 0.05 and abs(rods[0]) < 0.1  # axis 1 stayed, axis 0 came back


def test_probe_move_over_a_link_slower_than_the_period_warns(tmp_path):
    """Modbus RTU takes about 2 ms a request, two controller periods: in real time the move runs
    slower than commanded. The report counts the overruns and warns that its times are in
    controller periods, not wall-clock time."""
    cfg = write_config(tmp_path, extra=QUIET_SENSORS, clock="realtime")
    emu = ModbusEmulator(bank_from_config(cfg, lockstep=False), modbus_map.load(), transport="rtu").start()
    try:
        result = CliRunner().invoke(probe, [emu.url, "--move", "--json", "--requests", "5", "--sine-hz", "10",
                                            "--step-mm", "0.5"])
        report = json.loads(result.stdout)
    finally:
        emu.stop()
    assert result.exit_code == 0, (result.output, report.get("error"))
    move = report["move"]
    assert move["clock_overruns"] > 100 and "ran slower than commanded" in move["warning"]
    assert report["hold"]["confirmed"]


def test_probe_move_step_figures_do_not_depend_on_the_steps_sign(tmp_path):
    """The emulated actuator is symmetric, so a step of -2 mm has the rise time and overshoot of
    a step of +2 mm (10 % and 90 % of the step reached in its own direction)."""
    figures = []
    for step in ("2", "-2"):
        (tmp_path / step).mkdir()
        result, report, holding, _ = probe_move(tmp_path / step, "--step-mm", step, "--sine-hz", "2")
        assert result.exit_code == 0, report.get("error")
        figures.append((report["move"]["rise_time_s"], report["move"]["overshoot_pct"]))
    (rise_up, over_up), (rise_down, over_down) = figures
    assert rise_up > 0.005 and rise_down == pytest.approx(rise_up, abs=2 / 1024)
    assert over_up >= 0 and over_down == pytest.approx(over_up, abs=0.5)
