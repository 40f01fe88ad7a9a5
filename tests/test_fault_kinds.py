"""The fault kinds of the load cell, the mode switch and the drive's warning (docs/faults.md):
`mode`, `fspike`, `fstuck`, `fnan`, `warn`. Each ends in the outcome docs/faults.md gives, run
end to end: `hsio run` against `hsio emulate` in another process over Modbus TCP on 127.0.0.1
and over CANopen (SLCAN), or against the emulator in the test's process over Modbus TCP."""

from __future__ import annotations

import itertools
import json
import logging
import os
import re

import numpy as np
import pytest

from hsio.commands.emulate import bank_from_config
from hsio.drivers import modbus_map
from hsio.emulators.faults import KINDS, RECOVERABLE, check_transport, parse
from hsio.emulators.canopen import CanopenEmulator
from hsio.emulators.modbus import ModbusEmulator
from hsio.errors import ConfigError
from hsio.experiment import ExperimentStopped
from hsio.interfaces import ControlMode
from test_emulate_cli import Emulator, hsio
from test_faults_runs import DRIVER, DURATION, QUIET_SENSORS, RATE, RUN, SCALE, TRANSPORTS, assert_safe, \
    emulator_config, read_steps
from wire import run

N_AVG = 4  # [test] n_avg's default: a step's force is the mean of its last 4 samples
CAPACITY_KN = 250.0  # the emulator's force_limit_kN: a force jump above half of it is refused
FAULT_TICK = 700  # step 35 of 20 ticks
LAST_SAMPLE_TICK = 716  # among the last N_AVG samples of step 36
_channels = itertools.count()


# --- SPEC ---------------------------------------------------------------------------------------

def test_the_new_kinds_parse_with_their_defaults_and_the_random_schedule_keeps_its_kinds():
    got = [(f.kind, f.tick, f.arg) for f in parse("mode@5,fspike@6,fspike@7:150,fstuck@8:30,fnan@9,warn@10,"
                                                    "warn@11:0xFF01,warn@12:16912").faults]
    assert got == [("mode", 5, 0.0), ("fspike", 6, 50.0), ("fspike", 7, 150.0), ("fstuck", 8, 30.0),
                   ("fnan", 9, 0.0), ("warn", 10, 0x4210), ("warn", 11, 0xFF01), ("warn", 12, 0x4210)]
    assert {f.kind for f in parse("seed=3,every=100,until=100000").faults} == set(RECOVERABLE)
    assert {"mode", "fspike", "fstuck", "fnan", "warn"} <= set(KINDS)


@pytest.mark.parametrize("spec, words", [
    ("fstuck@100:0.5", "'fstuck@100:0.5': '0.5' is not a whole number"),
    ("warn@10:hot", "'warn@10:hot': 'hot' is not an EMCY code (e.g. 0x4210)"),
    ("warn@10:0x42", "'warn@10:0x42': 0x42 is not an EMCY error code (0x0100..0xFFFF; 0x00xx is the error reset)"),
    ("warn@10:0x10000", "is not an EMCY error code"),
    ("fnan@10:3", "'fnan@10:3': 3 is not in 0..0"),
    ("kinds=drop+fspoke", "unknown fault(s) 'fspoke'; known: drop, delay, corrupt, duplicate, restart, spike, "
                          "stuck, nan, valve, mode, fspike, fstuck, fnan, warn"),
])
def test_a_bad_argument_of_a_new_kind_is_refused_quoting_the_item(spec, words):
    with pytest.raises(ConfigError) as exc:
        parse(spec)
    assert words in str(exc.value)


def test_the_load_cell_faults_act_on_axis_0_s_force_only():
    schedule = parse("fspike@10:40,fnan@20,fstuck@30:3")
    schedule.due(10)
    assert schedule.measured_force(1, 10, 1.0) == 1.0  # another axis: untouched
    assert schedule.measured(0, 10, 2.0) == 2.0  # the displacement: untouched
    assert [schedule.measured_force(0, 10, 1.0) for _ in range(2)] == [41.0, 1.0]  # one reading
    schedule.due(20)
    assert np.isnan(schedule.measured_force(0, 20, 1.0)) and schedule.measured_force(0, 20, 1.0) == 1.0
    schedule.due(30)
    assert [schedule.measured_force(0, t, float(t)) for t in range(30, 35)] == [30.0, 30.0, 30.0, 33.0, 34.0]


def test_warn_is_refused_over_modbus_before_it_serves(tmp_path):
    """`warn` is a CANopen EMCY: a Modbus emulator given it refuses to start, naming the kind and
    both transports; `hsio emulate modbus` exits 2 before its banner."""
    bank = bank_from_config(emulator_config(tmp_path), lockstep=True)
    with pytest.raises(ConfigError, match=r"--faults: 'warn' \(at tick 300\) is a CANopen fault \(a warning EMCY\), "
                                          r"which a Modbus controller cannot send; refused over Modbus \(its kinds: "
                                          r"drop, .*fnan\)"):
        ModbusEmulator(bank, modbus_map.load(), faults=parse("drop@10,warn@300"))
    check_transport(parse("warn@300"), "canopen")  # CANopen's own
    proc = hsio("emulate", "modbus", "--port", "0", "--faults", "seed=1,every=50,kinds=drop+warn,until=100000",
                emulator_config(tmp_path), timeout=60)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "is a CANopen fault" in proc.stderr and "refused over Modbus" in proc.stderr
    assert "url" not in proc.stdout and "Traceback" not in proc.stderr


# --- end to end: `hsio emulate` in another process ------------------------------------------------

MIXED = """[structure]
name = "structure_I"
[record]
duration_s = 0.6
pga_g = 1.0
[integrator]
method = "mixed"
switch_rule = "initial_stiffness"
[test]
rate = 5.0
[output]
plots = false
[hardware]
clock = "lockstep"
"""
FIRST_SWITCH = 107  # the step of the mixed run's first switch of its one axis (the wall) to force control


def run_against(tmp_path, transport: str, spec: str, emulator_toml, run_toml: str, name: str):
    """`hsio emulate TRANSPORT --faults SPEC EMULATOR_TOML` and `hsio run` against it; (process,
    summary, steps), the emulator's output in ``process.emulator_said``."""
    emu = Emulator(*TRANSPORTS[transport][:1], "--faults", spec, *TRANSPORTS[transport][1:], "--watchdog-s", "5",
                   emulator_toml)
    try:
        cfg = tmp_path / f"{name}.toml"
        cfg.write_text(run_toml.replace("{url}", emu.lines["url"]))
        out = tmp_path / name
        proc = hsio("run", cfg, "--out", out, "--json", timeout=120)
    finally:
        said = emu.stop()
    proc.emulator_said = said
    summary = json.loads((out / "summary.json").read_text()) if (out / "summary.json").exists() else None
    return proc, summary, read_steps(out / "run.sqlite")


def dc_run(tmp_path, transport, spec, name):
    run_toml = RUN.format(duration=DURATION, scale=SCALE, rate=RATE, url="{url}") + QUIET_SENSORS + DRIVER
    return run_against(tmp_path, transport, spec, emulator_config(tmp_path), run_toml, name)


def slow_only(transport: str, kinds_here: tuple, kind: str) -> None:
    if transport != "tcp" and os.environ.get("HSIO_SLOW") != "1" and kind not in kinds_here:
        pytest.skip(f"over {transport}, without HSIO_SLOW=1, only what differs from TCP ({', '.join(kinds_here)})")


STOPS = {  # kind -> (SPEC, what stderr says over TCP, over CANopen)
    "fnan": (f"fnan@{FAULT_TICK}", "force nan is not finite", "force jumped -327."),
    "fspike": (f"fspike@{LAST_SAMPLE_TICK}:150", "force jumped +1", "force jumped +1"),
}


@pytest.mark.parametrize("transport", ["tcp", "canopen"])
@pytest.mark.parametrize("kind", list(STOPS))
def test_an_implausible_force_stops_the_run_as_an_interlock(transport, kind, tmp_path):
    """A NaN force (over CANopen the int16 "no value", -327.68 kN) and a jump above half the
    capacity are refused before the integrator sees them: exit 3, every step before kept."""
    slow_only(transport, ("fnan",), kind)
    spec, tcp_says, can_says = STOPS[kind]
    proc, summary, steps = dc_run(tmp_path, transport, spec, kind)
    assert proc.returncode == 3, proc.stderr
    for words in ("implausible measurement", tcp_says if transport == "tcp" else can_says, "the record is in",
                  "(at most 125 kN)" if kind == "fspike" else ""):
        assert words in proc.stderr, proc.stderr
    if kind == "fspike":  # the spike, less the force's change over the sample
        jump = float(re.search(r"force jumped \+([0-9.]+) kN", proc.stderr).group(1))
        assert jump == pytest.approx(150.0, abs=0.1)
    assert "Traceback" not in proc.stderr
    assert_safe(summary, steps)
    assert len(steps["step"]) == 35  # the step the fault hit (36) is not recorded


def test_a_warning_emcy_is_printed_once_and_the_run_completes(tmp_path):
    """`warn` twice over CANopen (SLCAN, `hsio emulate` in another process): the drive stays
    operation enabled; `hsio run` prints the warning once and completes, all its steps recorded.
    (About 10 s: with HSIO_SLOW=1; the in-process test below runs the same over a virtual bus.)"""
    if os.environ.get("HSIO_SLOW") != "1":
        pytest.skip("over SLCAN in another process with HSIO_SLOW=1; in process it runs always")
    proc, summary, steps = dc_run(tmp_path, "canopen", "warn@300,warn@700", "warn")
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.count("CANopen node 1: EMCY 0x4210") == 1, proc.stderr
    assert "a warning: the drive stays OPERATION ENABLED" in proc.stderr
    assert "injected 2: warn 2" in proc.emulator_said
    assert_safe(summary, steps)
    assert summary["steps"] == round(DURATION / 0.01)


# --- end to end: the emulator in the test's process, over Modbus TCP -------------------------------

def inprocess_run(tmp_path, spec: str | None, name: str, config=None):
    config = config or emulator_config(tmp_path)
    emu = ModbusEmulator(bank_from_config(config, lockstep=True, watchdog_s=5.0), modbus_map.load(),
                         faults=parse(spec) if spec else None).start()
    try:
        result, recorded = run(config, tmp_path / name, url=emu.url, driver={"stuck_samples": 8, "stuck_mm": 0.02})
    finally:
        emu.stop()
    return result, recorded.steps


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    result, steps = inprocess_run(tmp_path_factory.mktemp("ref"), None, "reference")
    assert result["exit_status"] == 0
    return steps


def test_a_force_spike_within_the_jump_bound_passes_into_its_step(reference, tmp_path):
    """50 kN, a fifth of the capacity, in the last samples of step 36: not refused (a change the
    check cannot tell from a real one); that step's force is off by 50 / n_avg kN and the run
    goes on from it."""
    result, steps = inprocess_run(tmp_path, f"fspike@{LAST_SAMPLE_TICK}", "fspike")
    assert result["exit_status"] == 0 and result["steps"] == len(reference["step"])
    off = steps["force_C1"] - reference["force_C1"]
    assert np.flatnonzero(np.abs(off) > 1e-6)[0] == 35  # step 36
    assert off[35] == pytest.approx(50.0 / N_AVG, abs=1e-5)
    assert np.array_equal(steps["force_C1"][:35], reference["force_C1"][:35])
    assert np.max(np.abs(steps["u_C1"] - reference["u_C1"])) > 0.1  # the integrator took it


def test_a_frozen_load_cell_stops_the_run_once_the_displacement_has_moved(reference, tmp_path):
    """`fstuck@700` (for good): axis 0's force reads the same from step 36 on while the specimen
    moves; once it has read the same for force_stuck_samples (512) samples and the displacement
    has moved over force_stuck_mm (1 mm) meanwhile, the run stops as on a stuck load cell, the
    steps before kept, the actuators holding. With the check off the run completes, its response
    wrong (docs/faults.md)."""
    result, steps = inprocess_run(tmp_path, f"fstuck@{FAULT_TICK}", "fstuck")
    assert isinstance(result, ExperimentStopped), result
    for words in ("actuator 'C1'", "force stuck at", "for 512 samples while the displacement moved over",
                  "a stuck or saturated load cell", "the actuators hold (confirmed by read-back)"):
        assert words in str(result), result
    n = len(steps["step"])
    assert FAULT_TICK // 20 + 512 // 20 <= n < len(reference["step"])  # 20 ticks a step
    frozen = steps["force_C1"][36:]
    assert np.all(frozen == frozen[0])
    config = emulator_config(tmp_path)
    emu = ModbusEmulator(bank_from_config(config, lockstep=True, watchdog_s=5.0), modbus_map.load(),
                         faults=parse(f"fstuck@{FAULT_TICK}")).start()
    try:
        result, recorded = run(config, tmp_path / "off", url=emu.url,
                               driver={"stuck_samples": 8, "stuck_mm": 0.02, "force_stuck_samples": 0})
    finally:
        emu.stop()
    steps = recorded.steps
    assert result["exit_status"] == 0 and result["steps"] == len(reference["step"])
    assert np.max(np.abs(steps["u_C1"] - reference["u_C1"])) > 1.0


def test_the_mode_fault_has_no_effect_on_a_run_that_never_switches(reference, tmp_path):
    """`mode@0` in displacement control only: nothing is switched, nothing differs."""
    result, steps = inprocess_run(tmp_path, "mode@0", "mode")
    assert result["exit_status"] == 0
    for name in reference:
        if name.startswith(("u_", "disp_", "force_", "target_")):
            assert np.array_equal(steps[name], reference[name]), name


def inprocess_emulator(transport: str, config, spec: str):
    bank = bank_from_config(config, lockstep=True, watchdog_s=5.0)
    if transport == "canopen":
        return CanopenEmulator(bank, f"hsio-kinds-{next(_channels)}", faults=parse(spec)).start()
    return ModbusEmulator(bank, modbus_map.load(), faults=parse(spec)).start()


@pytest.mark.parametrize("transport", ["tcp", "canopen"])
def test_a_switch_the_controller_ignores_stops_a_mixed_run_at_its_first_switch(transport, tmp_path):
    """`mode@100`: the wall (axis 0) goes on in displacement control; the run stops at its first
    switch to force control, naming the axis and both modes, the steps before kept, the axis
    holding in displacement control."""
    config = tmp_path / "mixed.toml"
    config.write_text(MIXED + QUIET_SENSORS)
    emu = inprocess_emulator(transport, config, "mode@100")
    try:
        result, recorded = run(config, tmp_path / "mode", url=emu.url)
    finally:
        emu.stop()
    assert isinstance(result, ExperimentStopped), result
    says = ("actuator 'wall' (axis 0) at modbus+tcp://", "force control asked for, but the controller reports "
            "displacement control") if transport == "tcp" else (
        "actuator 'wall' at canopen+virtual://", "force control (10 (CYCLIC SYNCHRONOUS TORQUE)) asked for, but the "
        "mode display 0x6061 shows 8 (CYCLIC SYNCHRONOUS POSITION)")
    for words in (*says, "did not take the mode switch", "the actuators hold (confirmed by read-back)"):
        assert words in str(result), result
    assert emu.bank.faults.injected == {"mode": 1}
    c = emu.bank.controllers[0]
    assert c.holding and c.mode is ControlMode.DISPLACEMENT
    steps = recorded.steps
    assert FIRST_SWITCH - 2 <= len(steps["step"]) == result.result.steps <= FIRST_SWITCH - 1
    assert set(steps["mode_wall"]) == {"displacement"}


def test_a_warning_emcy_over_canopen_is_logged_once_and_the_run_completes(tmp_path, caplog):
    """`warn` twice, then a lab's own code listed in [driver] emcy_warnings: each code logged
    once as a warning, the run completes; a code that is no warning stops it as a drive fault."""
    config = emulator_config(tmp_path)
    emu = inprocess_emulator("canopen", config, "warn@300,warn@500,warn@700:0xFF01")
    try:
        with caplog.at_level(logging.WARNING, logger="hsio.drivers.canopen"):
            result, recorded = run(config, tmp_path / "warn", url=emu.url, driver={"emcy_warnings": "0xFF01"})
    finally:
        emu.stop()
    assert isinstance(result, dict) and result["exit_status"] == 0, result
    said = [r.getMessage() for r in caplog.records if "EMCY" in r.getMessage()]
    assert len(said) == 2 and "EMCY 0x4210" in said[0] and "EMCY 0xFF01" in said[1], said
    assert all("a warning: the drive stays OPERATION ENABLED" in line for line in said)
    assert result["steps"] == len(recorded.steps["step"]) == round(DURATION / 0.01)

    emu = inprocess_emulator("canopen", config, "warn@700:0xFF01")  # not listed: a drive fault
    try:
        result, recorded = run(config, tmp_path / "fault", url=emu.url)
    finally:
        emu.stop()
    assert isinstance(result, ExperimentStopped) and "EMCY 0xFF01" in str(result), result
    assert len(recorded.steps["step"]) == 35
