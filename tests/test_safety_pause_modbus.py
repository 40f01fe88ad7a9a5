"""A real-time run over Modbus TCP paused for 2 s of wall time through the control socket
(docs/safety.md section 4): nothing moves while paused, the controller's host watchdog is kept
fed (a controller whose watchdog also watches holding axes does not latch), and the resumed run
equals the unpaused one (to 0.1 % of its peak). A host that goes silent while its axes hold
still trips that watchdog."""

from __future__ import annotations

import os
import threading
import time

import numpy as np
import pytest

from hsio import config as config_mod
from hsio import runner
from hsio.clock import RealTimeClock
from hsio.commands.emulate import bank_from_config
from hsio.drivers import canopen as canopen_driver
from hsio.drivers import modbus_map
from hsio.drivers.modbus import open_link
from hsio.emulators.canopen import CanopenEmulator
from hsio.emulators.modbus import ModbusEmulator
from hsio.recording import Run
from hsio.safety import socket as control_socket
from wire import QUIET_SENSORS, max_abs_diff, write_config

WATCHDOG_S = 1.0  # the emulator's default, half the pause: without the keep-alive it would latch
PAUSE_S = 2.0
PAUSE_AFTER = 20  # steps
SAFETY = "[safety]\ndry_run = false\nkeys = false\n[output]\nplots = false\nns = false\n"


def strict_emulator(cfg, watchdog_s: float = WATCHDOG_S):
    """A real-time emulated controller whose host watchdog also watches the axes it holds."""
    bank = bank_from_config(cfg, lockstep=False, watchdog_s=watchdog_s)
    bank.watch_holding = True
    return ModbusEmulator(bank, modbus_map.load()).start()


def run_over_modbus(tmp_path, name: str, pause: bool, watchdog_s: float = WATCHDOG_S, pause_s: float = PAUSE_S):
    """60 steps at TR 3 in real time (1.8 s of lab time); with ``pause``, a pause of ``pause_s`` of
    wall time after step 20 through the run's control socket, the emulator (host watchdog
    ``watchdog_s``, watching holding axes) watched throughout."""
    cfg_path = write_config(tmp_path, duration=0.6, rate=3.0, clock="realtime", name=f"{name}.toml")
    cfg_path.write_text(cfg_path.read_text().replace("[output]\nplots = false\nsamples = false\n", "")
                        .replace("[record]\n", "[record]\nscale = 4.0\n")
                        + QUIET_SENSORS + SAFETY)
    emu = strict_emulator(cfg_path, watchdog_s)
    out = tmp_path / name
    seen: dict = {"rods": [], "expired": [], "counters": [], "replies": []}

    def operator():
        path = out / "control.sock"
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            try:
                status = control_socket.send(path, "status") if path.exists() else ""
            except OSError:
                status = ""
            if "phase HS" in status and int(status.rpartition(" ")[2]) >= PAUSE_AFTER:
                break
            time.sleep(0.005)
        seen["replies"].append(control_socket.send(path, "pause"))
        while not control_socket.send(path, "status").startswith("ok paused") and time.monotonic() < deadline:
            time.sleep(0.005)
        began = time.monotonic()
        while time.monotonic() < began + pause_s:
            bank = emu.bank
            with bank.lock:
                seen["rods"].append([c.d_rod for c in bank.controllers])
                seen["expired"].append([a.watchdog_expired for a in bank.axes])
                seen["counters"].append(bank.axes[0].watchdog_value)
            time.sleep(0.05)
        seen["paused_s"] = time.monotonic() - began
        seen["replies"].append(control_socket.send(path, "resume"))

    thread = threading.Thread(target=operator, daemon=True) if pause else None
    try:
        cfg = config_mod.load(cfg_path)
        cfg["hardware"]["url"] = emu.url
        if thread:
            thread.start()
        summary = runner.run(cfg, out)
        if thread:
            thread.join(timeout=30)
        seen["latched_after"] = any(a.watchdog_expired for a in emu.bank.axes)
    finally:
        emu.stop()
    return summary, Run(out / "run.sqlite"), seen


def test_a_real_time_modbus_run_paused_for_2_s_holds_still_and_resumes_to_the_same_result(tmp_path):
    ref_summary, ref, _ = run_over_modbus(tmp_path, "unpaused", pause=False)
    summary, run, seen = run_over_modbus(tmp_path, "paused", pause=True)
    assert seen["replies"] == ["ok pausing", "ok resuming"]
    assert summary["steps"] == ref_summary["steps"] == 60 and summary["exit_status"] == 0
    assert seen["paused_s"] >= PAUSE_S and len(seen["rods"]) > 20

    # The emulator saw no motion and no latched watchdog while paused, because the host kept
    # changing the watchdog counter of the holding axes.
    rods = np.array(seen["rods"])
    assert float(np.max(np.ptp(rods, axis=0))) < 1e-9
    assert not any(any(e) for e in seen["expired"]) and not seen["latched_after"]
    counters = [c for c in seen["counters"] if c is not None]
    assert len(set(counters)) >= 10  # fed throughout the pause (every 0.1 s, sampled every 0.05 s)

    # The record: one pause and one resume, the hold confirmed by read-back; across the gap in
    # lab time (the pause) the measured displacement of each actuator did not change.
    events = {e["kind"]: e["message"] for e in run.events()}
    assert "the actuators hold (confirmed by read-back)" in events["pause"], events
    assert events["resume"].startswith("resumed after 2.")
    samples = run.samples()
    lab = samples["lab_time_s"]
    gap = int(np.argmax(np.diff(lab)))
    # the pause, between two samples: the controller clock (ticks of its own loop, which can
    # run late on a loaded machine) advanced by most of the 2 s, against 1 ms between samples
    assert np.diff(lab)[gap] >= 0.5 * PAUSE_S
    assert PAUSE_AFTER <= samples["step"][gap] < 60  # asked at step 20, acted on at a step boundary
    for name in (k for k in samples if k.startswith("disp_")):
        before, after = samples[name][gap - 5:gap + 1], samples[name][gap + 1]
        command = samples["cmd_" + name[len("disp_"):]][gap]
        creep = float(np.max(np.abs(np.diff(before))))  # the servo's last approach, per sample
        assert creep < 1e-2  # the commands had come to rest when the hold came (the servo closing in)
        # 2 s later the actuator stands where it stood, but for the last of its approach to the
        # command it was given (moving at the creep's rate it would be ~2000 x further away); the
        # sensors are noise-free
        assert abs(after - before[-1]) <= abs(command - before[-1]) + creep + 1e-5, name

    # The result equals the unpaused run: the pause leaves no trace (measured 2e-8 mm, against a
    # peak of 1.7 mm); 0.1 % of the unpaused run's peak is the bound.
    tracking = max(ref_summary["rms_tracking_error_mm"])
    peak = max(ref_summary["peak_displacement_mm"])
    diff = max_abs_diff(ref, run)
    print(f"pause over Modbus TCP: max |paused - unpaused| {diff:.2e} mm, unpaused tracking RMS {tracking:.4f} mm, "
          f"peak {peak:.3f} mm")
    assert peak > 1.0
    assert diff < 1e-3 * peak


@pytest.mark.parametrize("protocol", ["modbus", "canopen"])
def test_a_silent_host_trips_the_watchdog_of_holding_axes(tmp_path, protocol):
    """The keep-alive is the host's doing: a host that holds its axes and keeps them alive (Modbus:
    the watchdog register alone; CANopen: the halted drive's RPDO2) does not get them latched; one
    that then falls silent does (Modbus: the watchdog bit; CANopen: FAULT with EMCY 0x8130)."""
    cfg = write_config(tmp_path, duration=0.3, clock="realtime")
    watchdog_s = 1.0  # fed every 0.05 s: a 20-fold margin on a loaded machine
    if protocol == "modbus":
        emu = strict_emulator(cfg, watchdog_s)
        actuators = open_link(emu.url, ["C1", "C2"], RealTimeClock())
    else:
        bank = bank_from_config(cfg, lockstep=False, watchdog_s=watchdog_s)
        bank.watch_holding = True
        emu = CanopenEmulator(bank, f"hsio-keep-alive-{os.getpid()}").start()
        actuators = canopen_driver.open_link(emu.url, ["C1", "C2"], RealTimeClock())
    try:
        for a in actuators:
            a.hold()
        assert all(a.holding() for a in actuators)  # read back from the controller
        for _ in range(round(1.5 * watchdog_s / 0.05)):  # a pause of 1.5 watchdog times, fed
            for a in actuators:
                a.keep_alive()
            time.sleep(0.05)
        assert not any(a.watchdog_expired for a in emu.bank.axes)
        assert all(c.holding for c in emu.bank.controllers)
        assert [a.tripped() for a in actuators] == [None, None]  # what a paused run watches
        time.sleep(2 * watchdog_s)  # the host falls silent
        assert all(a.watchdog_expired for a in emu.bank.axes)
        said = "host watchdog expired" if protocol == "modbus" else "in FAULT (statusword 0x"
        assert all(said in a.tripped() for a in actuators)  # read from the controller, as a pause does
        if protocol == "modbus":
            actuators[0].link.read_status()
            assert all(actuators[0].link.map.bit(st["status_word"], "watchdog") for st in actuators[0].link.status)
        else:
            words = [d.sdo_read(0x6041, what="statusword") for d in actuators[0].link.drives]
            assert all(w & 0x4F == 0x08 for w in words)  # FAULT
        assert all(a.holding() for a in actuators)  # a latched watchdog holds
        for a in actuators:
            try:
                a.close()
            except Exception:
                pass  # a drive in FAULT does not confirm the halt; it holds anyway
    finally:
        emu.stop()


def test_a_watchdog_shorter_than_the_pause_wait_is_fed_from_what_the_controller_reports(tmp_path, monkeypatch):
    """A controller whose host watchdog (0.8 s, read by the driver from its info registers) is
    shorter than the pause's wait (made 2 s here, so that the run's own steps keep a watchdog a
    loaded machine can meet): the wait feeds it every quarter of that time, so a pause of 3 s
    latches nothing and the run resumes to the end."""
    from hsio.safety.control import RunControl

    monkeypatch.setattr(RunControl, "WAIT_SLICE_S", 2.0)
    summary, run, seen = run_over_modbus(tmp_path, "short", pause=True, watchdog_s=0.8, pause_s=3.0)
    assert seen["replies"] == ["ok pausing", "ok resuming"]
    assert summary["exit_status"] == 0 and summary["steps"] == 60
    assert seen["paused_s"] >= 3.0 and len(seen["rods"]) > 10
    assert not any(any(e) for e in seen["expired"])  # (a latch after the resume would have stopped the run)
    assert float(np.max(np.ptp(np.array(seen["rods"]), axis=0))) < 1e-9  # held still throughout
