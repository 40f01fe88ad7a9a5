"""Round-trip latency of each transport and the time of a full integration step over Modbus TCP
and CANopen, next to the raw request round trip of the same library measured in the same run.

The ratio driver / raw is the framework's overhead. Prints a table; asserts nothing.

    python bench/bench_transport.py [--requests 2000]
"""

from __future__ import annotations

import argparse
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from hsio.drivers import modbus_map
from hsio.drivers.canopen import open_link as canopen_link
from hsio.drivers.modbus import open_link as modbus_link
from hsio.commands.emulate import bank_from_config
from hsio.emulators.canopen import CanopenEmulator
from hsio.emulators.modbus import ModbusEmulator
from hsio import config as config_mod
from hsio.clock import LockstepClock
from hsio.control_loop import ControlLoop
from hsio.api import simulate
from hsio.hardware import open_hardware
from hsio.runner import build_record
from hsio.structures import get_structure
from hsio.sites import ActuatorSite

CONFIG = """
[record]
duration_s = 0.5
[output]
plots = false
samples = false
"""


def stats(samples) -> str:
    ms = np.asarray(samples) * 1e3
    return f"median {np.median(ms):7.3f}  p99 {np.percentile(ms, 99):7.3f}  max {ms.max():7.3f} ms"


# The controllers' host watchdog, long enough for the timed loops of raw requests (which send no
# command) on a slow machine: the bench measures the transport, not the watchdog.
WATCHDOG_S = 60.0


def timed(fn, n: int) -> list[float]:
    out = []
    for _ in range(n):
        t = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t)
    return out


def step_time(url: str, cfg) -> tuple[float, float]:
    """Wall time of one integration step (median) and controller periods per step."""
    structure = get_structure(cfg["structure"]["name"])
    ground = build_record(cfg, structure)
    clock = LockstepClock()
    actuators = open_hardware(url, structure.experimental, clock, {})
    loop = ControlLoop(actuators, clock, structure.dt, cfg["test"]["rate"], n_avg=cfg["test"]["n_avg"],
                       keep_samples=False, hold_fraction=cfg["test"]["hold_fraction"])
    sub = ActuatorSite(loop)
    times = []
    original = sub.set_trial

    def timed_trial(commands, modes):  # one integration step of alpha-OS: one trial, sent and measured
        t = time.perf_counter()
        original(commands, modes)
        times.append(time.perf_counter() - t)

    sub.set_trial = timed_trial
    try:
        result = simulate(structure, ground, sub, "alpha_os", cfg["integrator"]["alpha"])
    finally:
        sub.close()
    return float(np.median(times)), clock.ticks / max(len(result.t) - 1, 1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--requests", type=int, default=2000)
    n = ap.parse_args().requests
    tmp = Path(tempfile.mkdtemp())
    cfg_path = tmp / "bench.toml"
    cfg_path.write_text(CONFIG)
    cfg = config_mod.load(cfg_path)
    names = [e.name for e in get_structure(cfg["structure"]["name"]).experimental]
    rows = []

    # -- Modbus TCP and RTU --------------------------------------------------------------------
    for transport in ("tcp", "rtu"):
        emu = ModbusEmulator(bank_from_config(cfg_path, lockstep=True, watchdog_s=WATCHDOG_S), modbus_map.load(), transport).start()
        clock = LockstepClock()
        acts = modbus_link(emu.url, names, clock, {})
        link = acts[0].link
        k = n if transport == "tcp" else max(n // 10, 50)
        rs, rc = link.map.status_span(len(names))
        ws, wc = link.map.command_span(len(names), True)
        words = [0] * wc
        raw_read = timed(lambda: link.client.read_holding_registers(rs, count=rc, device_id=1), k)
        drv_read = timed(link.read_status, k)
        raw_rw = timed(lambda: link.client.readwrite_registers(read_address=rs, read_count=rc, write_address=ws + 2,
                                                               values=words[2:], device_id=1), k)

        def tick():
            for a in acts:
                a.command(0.0)
            clock.tick()
            acts[0].feedback()
        drv_tick = timed(tick, k)
        rows.append((f"Modbus {transport.upper()}", "raw read (fn 3)", raw_read, "driver status read", drv_read))
        rows.append((f"Modbus {transport.upper()}", "raw write+read (fn 23)", raw_rw, "lockstep tick, 2 axes", drv_tick))
        for a in acts:
            a.close()
        emu.stop()

    # -- CANopen on the virtual bus ---------------------------------------------------------------
    emu = CanopenEmulator(bank_from_config(cfg_path, lockstep=True, watchdog_s=WATCHDOG_S), "bench").start()
    clock = LockstepClock()
    acts = canopen_link(emu.url, names, clock, {})
    link = acts[0].link
    node = link.drives[0].node
    raw_sdo = timed(lambda: node.sdo.upload(0x6041, 0), n)
    drv_sdo = timed(lambda: link.drives[0].sdo_read(0x6041), n)
    got = threading.Event()
    cobs = [0x280 + d.id for d in link.drives]
    seen = set()

    def on_tpdo(can_id, data, ts):
        seen.add(can_id)
        if len(seen) == len(cobs):
            got.set()
    for c in cobs:
        link.network.subscribe(c, on_tpdo)

    def raw_sync():
        got.clear()
        seen.clear()
        for d in link.drives:
            link.network.send_message(0x300 + d.id, b"\0" * 6)
        link.network.sync.transmit()
        got.wait(1.0)
    raw_cycle = timed(raw_sync, n)
    link.ticks = link.drives[0].sdo_read(0x2101)
    for c in cobs:
        link.network.unsubscribe(c, on_tpdo)
        link.network.subscribe(c, next(d.on_tpdo2 for d in link.drives if 0x280 + d.id == c))

    def tick():
        for a in acts:
            a.command(0.0)
        clock.tick()
        acts[0].feedback()
    drv_tick = timed(tick, n)
    rows.append(("CANopen virtual", "raw SDO upload", raw_sdo, "driver SDO read", drv_sdo))
    rows.append(("CANopen virtual", "raw RPDOs+SYNC->TPDOs", raw_cycle, "lockstep tick, 2 axes", drv_tick))
    for a in acts:
        a.close()
    emu.stop()

    print(f"Round trips ({n} requests; RTU {max(n // 10, 50)}), 127.0.0.1 / pty / python-can virtual bus")
    print(f"{'transport':<16} {'raw library request':<24} {'':<44} {'hsio driver':<22} {'':<44} ratio")
    for transport, raw_name, raw, drv_name, drv in rows:
        ratio = np.median(drv) / np.median(raw)
        print(f"{transport:<16} {raw_name:<24} {stats(raw):<44} {drv_name:<22} {stats(drv):<44} {ratio:5.2f}")

    # -- full integration steps -----------------------------------------------------------------
    print()
    print(f"Integration step (validation structure, TR {cfg['test']['rate']:g}, lockstep, median over the record)")
    local_s, ticks = step_time("emulator://", cfg)
    print(f"{'in process':<16} {local_s * 1e3:8.2f} ms per step ({ticks:.0f} controller periods)")
    for label, make in (("Modbus TCP", lambda: ModbusEmulator(bank_from_config(cfg_path, lockstep=True, watchdog_s=WATCHDOG_S), modbus_map.load(), "tcp")),
                        ("CANopen", lambda: CanopenEmulator(bank_from_config(cfg_path, lockstep=True, watchdog_s=WATCHDOG_S), "bench-step"))):
        emu = make().start()
        try:
            step_s, ticks = step_time(emu.url, cfg)
        finally:
            emu.stop()
        raw = [r for r in rows if r[0].startswith(label.split()[0]) and ("23" in r[1] or "SYNC" in r[1])][0][2]
        floor = ticks * float(np.median(raw))
        print(f"{label:<16} {step_s * 1e3:8.2f} ms per step ({ticks:.0f} periods; raw library floor "
              f"{floor * 1e3:.2f} ms = periods x raw cyclic request; ratio {step_s / floor:.2f})")


if __name__ == "__main__":
    main()
