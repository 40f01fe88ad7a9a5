"""Period jitter of a 1024 Hz real-time command loop, in process and over Modbus TCP.

Each period the loop commands every axis of the validation structure and reads its feedback:
in process through the emulated controllers (``emulator://``), and over Modbus TCP to the
emulator's server (in a process of its own) on 127.0.0.1, a port the system chooses, through
hsio's Modbus driver. The
loop sleeps to just before its deadline and busy-waits the rest, in a dedicated thread, with
CPU affinity and SCHED_FIFO where the OS grants them. Printed: the lateness of the period starts
(p50, p99, max, in microseconds) and the overruns per 10,000 periods.

    python bench/bench_jitter.py [--periods N] [--json]
"""

from __future__ import annotations

import argparse
import json
import math

from hsio.clock import RealTimeClock
from hsio.rths.realtime import run_periodic
from hsio.structures import get_structure

RATE = 1024.0


def _sine(k: int) -> float:
    return 1.0 * math.sin(2 * math.pi * 1.0 * k / RATE)  # mm


def _loop(actuators, periods: int) -> dict:
    def work(k: int) -> None:
        x = _sine(k)
        for a in actuators:
            a.command(x)
        for a in actuators:
            a.feedback()

    return run_periodic(work, RATE, periods, max_seconds=periods / RATE * 3 + 5, pin_cpu=-1, fifo_priority=50).stats()


def in_process(periods: int) -> dict:
    from hsio.emulators.local import open_url

    elements = get_structure("validation").experimental
    acts = open_url("emulator://", elements, RealTimeClock(RATE), {})
    try:
        return _loop(acts, periods)
    finally:
        for a in acts:
            a.close()


EMULATOR = """
import os, sys
try:  # the controller's own process: the other CPU and real-time priority where granted
    cpus = sorted(os.sched_getaffinity(0))
    os.sched_setaffinity(0, {cpus[0]})
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(40))
except (AttributeError, OSError):
    pass
from hsio.drivers import modbus_map
from hsio.commands.emulate import bank_from_config
from hsio.emulators.modbus import ModbusEmulator
emu = ModbusEmulator(bank_from_config(None, lockstep=False, watchdog_s=0), modbus_map.load(),
                     host="127.0.0.1", port=0).start()
print(emu.port, flush=True)
sys.stdin.read()  # serve until the bench closes our stdin
emu.stop()
"""


def over_modbus(periods: int) -> dict:
    """The emulator's Modbus server in a process of its own (as a servo controller is a machine of
    its own: no shared interpreter lock with the loop), on 127.0.0.1, a port the system chooses."""
    import subprocess
    import sys

    from hsio.drivers.modbus import open_link

    names = [e.name for e in get_structure("validation").experimental]
    server = subprocess.Popen([sys.executable, "-c", EMULATOR], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        port = int(server.stdout.readline())
        acts = open_link(f"modbus+tcp://127.0.0.1:{port}", names, RealTimeClock(RATE))
        try:
            return _loop(acts, periods)
        finally:
            for a in acts:
                a.close()
    finally:
        server.stdin.close()
        try:
            server.wait(timeout=10)
        except subprocess.TimeoutExpired:
            server.kill()
            server.wait(timeout=5)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--periods", type=int, default=10_000)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    if not 100 <= args.periods <= 100_000:  # refused, never clamped: the table must say what was measured
        ap.error(f"--periods {args.periods}: give 100 to 100000 periods")
    periods = args.periods
    rows = {"in process": in_process(periods), "Modbus TCP (127.0.0.1)": over_modbus(periods)}
    if args.json:
        print(json.dumps(rows, indent=1))
        return
    print(f"real-time command loop at {RATE:.0f} Hz, {periods} periods; lateness of the period start")
    print(f"{'path':<24} {'p50 us':>8} {'p99 us':>8} {'max us':>9} {'overruns/10k':>13} {'work p50 us':>12} {'work p99 us':>12}  granted")
    for name, s in rows.items():
        granted = f"affinity cpu {s['affinity']}" if s["affinity"] is not None else "no affinity"
        granted += ", SCHED_FIFO" if s["sched_fifo"] else ", no SCHED_FIFO"
        print(f"{name:<24} {s['p50_us']:8.1f} {s['p99_us']:8.1f} {s['max_us']:9.1f} {s['overruns_per_10k']:13.1f} "
              f"{s['work_p50_us']:12.1f} {s['work_p99_us']:12.1f}  {granted}")
        if s["periods"] < s["periods_requested"]:
            print(f"{'':<24} stopped by the time bound after {s['periods']} of {s['periods_requested']} periods")


if __name__ == "__main__":
    main()
