"""Faults injected by `hsio emulate ... --faults SPEC` (another process) during `hsio run` over
Modbus TCP, Modbus RTU and CANopen (SLCAN across processes): no step lost or duplicated, no
command beyond the limits or jumping, no implausible value reaching the integrator, and the
outcome docs/faults.md documents for each kind."""

from __future__ import annotations

import json
import math
import os
import sqlite3

import numpy as np
import pytest

from hsio import config as config_mod
from hsio import runner
from hsio.commands.emulate import bank_from_config
from hsio.drivers import modbus_map
from hsio.emulators.canopen import slcan_emulator
from hsio.emulators.modbus import ModbusEmulator
from test_emulate_cli import Emulator, hsio
from wire import QUIET_SENSORS, write_config

DURATION, RATE, SCALE = 1.0, 2.0, 4.0  # 100 steps of 20 controller periods, peaks of a few mm
TICKS_PER_STEP = round(RATE * 0.01 * 1024)
FAULT_TICK = 700  # about a third into the run
HALF_STROKE, VELOCITY = 127.0, 500.0
RECOVERABLE = "drop@300,delay@500:0.05,corrupt@700,duplicate@900,drop@1100,corrupt@1300,duplicate@1500"
STOPS = {  # kind -> (SPEC, exit code, what stderr says)
    "restart": (f"restart@{FAULT_TICK}", 3, "restarted"),
    "spike": (f"spike@{FAULT_TICK}:40", 3, "implausible measurement: displacement jumped"),
    "stuck": (f"stuck@{FAULT_TICK}", 3, "stuck transducer"),
    "nan": (f"nan@{FAULT_TICK}", 3, "implausible measurement"),
    "valve": (f"valve@{FAULT_TICK}", 3, "interlock"),
}
# Without HSIO_SLOW, the stops run over RTU and CANopen where the transport makes a difference:
# a restart over a serial line (RTU: reconnect, boot id), and over CANopen the boot-up message and
# the int32 "no value" of a NaN reading; RTU's NaN is TCP's (the same driver and register map).
CI_STOPS = {"rtu": ("restart",), "canopen": ("nan", "restart")}
DRIVER = "[driver]\nstuck_samples = 8\nstuck_mm = 0.02\ntimeout_s = 0.3\nretries = 3\n"
TRANSPORTS = {
    "tcp": ["modbus", "--port", "0"],
    "rtu": ["modbus-rtu"],
    "canopen": ["canopen", "--slcan", "tcp"],
}


RUN = """[record]
duration_s = {duration}
scale = {scale}
[test]
rate = {rate}
[output]
plots = false
samples = false
[hardware]
clock = "lockstep"
url = "{url}"
"""


def emulator_config(tmp_path):
    return write_config(tmp_path, duration=DURATION, rate=RATE, extra=QUIET_SENSORS, name="emulator.toml")


def read_steps(path):
    db = sqlite3.connect(path)
    cols = [r[1] for r in db.execute("PRAGMA table_info(steps)") if r[2] != "TEXT"]
    rows = db.execute(f"SELECT {', '.join(cols)} FROM steps ORDER BY step").fetchall()
    db.close()
    data = np.array(rows, dtype=float).reshape(-1, len(cols))
    return {c: data[:, k] for k, c in enumerate(cols)}


def run_over(tmp_path, transport: str, spec: str, name: str):
    """`hsio emulate TRANSPORT --faults SPEC` and `hsio run` against it; (process, summary, steps)."""
    args = [*TRANSPORTS[transport], "--watchdog-s", "5", emulator_config(tmp_path)]
    if spec:
        args[1:1] = ["--faults", spec]
    emu = Emulator(*args)
    try:
        cfg = tmp_path / f"{name}.toml"
        cfg.write_text(RUN.format(duration=DURATION, scale=SCALE, rate=RATE, url=emu.lines["url"]) + QUIET_SENSORS + DRIVER)
        out = tmp_path / name
        proc = hsio("run", cfg, "--out", out, "--json", timeout=240)
    finally:
        proc.emulator_said = emu.stop() if "proc" in locals() else emu.stop()
    assert (out / "run.sqlite").exists(), proc.stderr
    summary = json.loads((out / "summary.json").read_text()) if (out / "summary.json").exists() else None
    return proc, summary, read_steps(out / "run.sqlite")


def assert_safe(summary, steps):
    """No step lost or duplicated; targets and commands within the stroke and without jumps;
    every measurement the integrator saw finite and within the stroke."""
    n = len(steps["step"])
    assert summary is not None and summary["steps"] == n
    assert list(steps["step"]) == list(range(1, n + 1))  # none lost, none twice
    max_move = VELOCITY * RATE * 0.01  # what the actuator can travel in one step
    for name, values in steps.items():
        if name.startswith(("target_", "command_")):
            assert np.all(np.abs(values) <= HALF_STROKE)
            assert np.all(np.abs(np.diff(values)) <= max_move)
        if name.startswith(("disp_", "force_", "u_")):
            assert np.all(np.isfinite(values)) and np.all(np.abs(values) <= (HALF_STROKE if name[0] != "f" else 250.0))


@pytest.fixture(scope="module", params=list(TRANSPORTS))
def transport(request):
    return request.param


def in_process_emulator(transport: str, tmp_path):
    """The emulator of ``transport`` in this process, over the same wire (lockstep)."""
    bank = bank_from_config(emulator_config(tmp_path), lockstep=True, watchdog_s=5.0)
    if transport == "canopen":
        return slcan_emulator(bank, "tcp")
    return ModbusEmulator(bank, modbus_map.load(), transport=transport).start()


@pytest.fixture(scope="module")
def reference(transport, tmp_path_factory):
    """The fault-free run, in this process against an in-process emulator over the same transport:
    lockstep and noise-free, its result does not depend on the process it runs in (and two
    processes fewer per transport)."""
    tmp = tmp_path_factory.mktemp("ref")
    emu = in_process_emulator(transport, tmp)
    try:
        cfg = tmp / "reference.toml"
        cfg.write_text(RUN.format(duration=DURATION, scale=SCALE, rate=RATE, url=emu.url) + QUIET_SENSORS + DRIVER)
        summary = runner.run(config_mod.load(cfg), tmp / "reference")
    finally:
        emu.stop()
    assert summary["exit_status"] == 0
    return summary, read_steps(tmp / "reference" / "run.sqlite")


def test_recoverable_faults_change_nothing(transport, reference, tmp_path):
    """Lost requests, late and cut-short replies, repeated frames: retried, and the run is the
    fault-free run, step for step."""
    proc, summary, steps = run_over(tmp_path, transport, RECOVERABLE, "faulty")
    assert proc.returncode == 0, proc.stderr
    assert f"faults    injected {RECOVERABLE.count('@')}:" in proc.emulator_said, proc.emulator_said
    assert_safe(summary, steps)
    ref_summary, ref_steps = reference
    assert summary["steps"] == ref_summary["steps"] == round(DURATION / 0.01)
    for name in ref_steps:
        if name.startswith(("u_", "disp_", "force_", "target_")):
            assert np.array_equal(steps[name], ref_steps[name]), name


@pytest.mark.parametrize("kind", list(STOPS))
def test_faults_that_stop_the_run(transport, kind, tmp_path):
    if transport != "tcp" and os.environ.get("HSIO_SLOW") != "1" and kind not in CI_STOPS[transport]:
        pytest.skip("every stop kind runs over Modbus TCP; RTU and CANopen run what differs from TCP "
                    f"({', '.join(CI_STOPS[transport])}) unless HSIO_SLOW=1")
    spec, code, says = STOPS[kind]
    proc, summary, steps = run_over(tmp_path, transport, spec, kind)
    assert proc.returncode == code, proc.stderr
    assert says in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr
    assert "the record is in" in proc.stderr
    assert_safe(summary, steps)
    # every step before the fault is kept; the step the fault hit is not recorded
    assert FAULT_TICK // TICKS_PER_STEP - 2 <= len(steps["step"]) <= FAULT_TICK // TICKS_PER_STEP + 2
