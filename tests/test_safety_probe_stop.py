"""A signal during `hsio probe --move` stops the move at once, as it stops a run (docs/safety.md
sections 3 and 4): the axis holds where it stands, the hold is read back and reported, exit status
5. So does any other error during the move (exit 3). The emulated controller runs in real time
with its host watchdog off, so that what holds the axis is the probe's hold and nothing else."""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import time

import pytest
from click.testing import CliRunner

from hsio.commands import probe as probe_mod
from hsio.commands.emulate import bank_from_config
from hsio.drivers import modbus_map
from hsio.emulators.modbus import ModbusEmulator
from wire import QUIET_SENSORS, write_config

HSIO = [sys.executable, "-c", "import sys; from hsio.entry import main; sys.argv[0] = 'hsio'; sys.exit(main())"]
SINE = ["--sine-mm", "5", "--sine-hz", "0.1"]  # 20 s of sine, after a 1 mm step and its way back (0.8 s)
IN_THE_SINE_MM = 1.5  # a command beyond the step's 1 mm: the sine has begun (0.5 s into it)


def realtime_emulator(tmp_path):
    cfg = write_config(tmp_path, clock="realtime", extra=QUIET_SENSORS)
    return ModbusEmulator(bank_from_config(cfg, lockstep=False, watchdog_s=0.0), modbus_map.load()).start()


def wait_until(predicate, timeout_s: float, proc) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline or proc.poll() is not None:
            raise AssertionError(f"the probe never got there; it printed {proc.communicate(timeout=10)}")
        time.sleep(0.005)


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_a_signal_during_the_sine_stops_it_holds_the_axis_and_reports_the_hold(tmp_path, signum):
    emu = realtime_emulator(tmp_path)
    axis, servo = emu.bank.axes[0], emu.bank.controllers[0]
    # SIGINT as from an interactive shell: a process started with it ignored (a pytest-xdist
    # worker's child) keeps ignoring it, by design (hsio.entry)
    proc = subprocess.Popen([*HSIO, "probe", emu.url, "--move", "--requests", "5", *SINE],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        wait_until(lambda: axis.enabled and servo.command > IN_THE_SINE_MM, 30.0, proc)
        proc.send_signal(signum)
        out, err = proc.communicate(timeout=40)  # unstopped, the sine would end by itself after 20 s, exit 0
        held_at = servo.d_rod
        time.sleep(0.2)
        with emu.bank.lock:
            enabled, holding, rod = axis.enabled, servo.holding, servo.d_rod
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        emu.stop()
    name = signal.Signals(signum).name
    assert proc.returncode == 5, (out, err)
    assert f"hsio probe: stopped by {name} during the sine; axis 0 stands at " in err, err
    assert err.rstrip().endswith("the actuators hold (confirmed by read-back)"), err
    assert "hold       the actuators hold (confirmed by read-back)" in out
    assert not enabled and holding
    assert rod == pytest.approx(held_at, abs=1e-6)  # it holds where it stopped
    stands = float(re.search(r"axis 0 stands at (-?[\d.]+) mm", err).group(1))
    assert 1.0 < stands <= 5.0 and rod == pytest.approx(stands, abs=0.01)  # mid-sine, not back at the start


def test_an_unexpected_error_during_the_move_holds_and_reports(tmp_path, monkeypatch):
    """Any error, not only hsio's own, ends the move with the axis held and the hold read back."""
    cfg = write_config(tmp_path, extra=QUIET_SENSORS)
    emu = ModbusEmulator(bank_from_config(cfg, lockstep=True), modbus_map.load()).start()
    send = probe_mod._Guard.send
    sent = []

    def failing(self, command):
        sent.append(command)
        if len(sent) > 600:  # in the step's dwell, 1 mm away from the start
            raise RuntimeError("out of paper")
        return send(self, command)

    monkeypatch.setattr(probe_mod._Guard, "send", failing)
    try:
        result = CliRunner().invoke(probe_mod.probe, [emu.url, "--move", "--requests", "5", "--sine-hz", "2"])
        holding = emu.bank.controllers[0].holding and not emu.bank.axes[0].enabled
    finally:
        emu.stop()
    assert result.exit_code == 3, result.output
    assert "error      unexpected RuntimeError('out of paper')" in result.stderr
    assert "hold       the actuators hold (confirmed by read-back)" in result.stdout
    assert holding
