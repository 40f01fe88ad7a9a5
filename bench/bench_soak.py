"""Soak: a long hybrid simulation over Modbus TCP (127.0.0.1) with faults injected on a seeded
schedule (docs/faults.md). Prints steps, faults injected by kind, the driver's retries and
reconnects, requests, and wall time; checks that no step was lost or repeated.

    python bench/bench_soak.py [--steps 100000] [--every 2000] [--seed 7]

The emulator serves in a thread of this process over a real TCP socket; the run is `hsio run`'s
own pipeline (hsio.runner.run). A fault costs at most one request timeout (``--timeout``).
"""

from __future__ import annotations

import argparse
import sqlite3
import tempfile
import time
from pathlib import Path

import numpy as np

from hsio import config as config_mod
from hsio import runner
from hsio.drivers import modbus as modbus_driver
from hsio.drivers import modbus_map
from hsio.emulators import faults
from hsio.commands.emulate import bank_from_config
from hsio.emulators.modbus import ModbusEmulator

DT = 0.01  # the validation structure's time step
CONFIG = """
[record]
synthetic_duration_s = {duration}
pga_g = 0.15
[test]
rate = 0.5
hold_fraction = 0.0
n_avg = 1
[output]
plots = false
samples = false
ns = false
[hardware]
clock = "lockstep"
[emulator]
velocity_limit_mm_s = 2000.0
"""


def soak(steps: int, every: int, seed: int, timeout_s: float = 0.5, kinds=faults.RECOVERABLE,
         workdir: Path | None = None) -> dict:
    """Run ``steps`` integration steps over Modbus TCP with a seeded fault schedule; return figures."""
    work = Path(workdir or tempfile.mkdtemp(prefix="hsio-soak-"))
    cfg_path = work / "soak.toml"
    cfg_path.write_text(CONFIG.format(duration=steps * DT))
    schedule = faults.FaultSchedule(faults.random_faults(seed, every, kinds))
    emulator = ModbusEmulator(bank_from_config(cfg_path, lockstep=True, watchdog_s=5.0), modbus_map.load(),
                              faults=schedule).start()
    links = []
    original = modbus_driver.open_link

    def spy(*args, **kwargs):  # keeps the link for its counters
        actuators = original(*args, **kwargs)
        links.append(actuators[0].link)
        return actuators

    modbus_driver.open_link = spy
    try:
        cfg = config_mod.load(cfg_path)
        cfg["hardware"]["url"] = emulator.url
        cfg["driver"].update({"timeout_s": timeout_s, "retries": 4, "reconnect_delay_s": 0.0, "velocity_mm_s": 2000.0})
        started = time.perf_counter()
        summary = runner.run(cfg, work / "run")
        wall = time.perf_counter() - started
    finally:
        modbus_driver.open_link = original
        emulator.stop()
    db = sqlite3.connect(work / "run" / "run.sqlite")
    ids = np.array([r[0] for r in db.execute("SELECT step FROM steps ORDER BY step")])
    finite = db.execute("SELECT COUNT(*) FROM steps WHERE u_C1 IS NULL OR disp_C1 IS NULL").fetchone()[0] == 0
    db.close()
    link = links[0]
    return {
        "steps": int(summary["steps"]),
        "recorded": int(ids.size),
        "lost_or_repeated": int(steps - ids.size + (ids.size - np.unique(ids).size)),
        "consecutive": bool(ids.size and np.array_equal(ids, np.arange(1, ids.size + 1))),
        "finite": finite,
        "ticks": int(emulator.bank.ticks),
        "faults": dict(sorted(schedule.injected.items())),
        "faults_total": schedule.total,
        "requests": link.requests,
        "retries": link.reconnects,
        "wall_time_s": round(wall, 1),
        "stopped": summary["stopped"],
        "peak_displacement_mm": [round(x, 3) for x in summary["peak_displacement_mm"]],
        "run_file": str(work / "run" / "run.sqlite"),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=100_000)
    parser.add_argument("--every", type=int, default=2000, help="mean controller ticks between faults")
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--timeout", type=float, default=0.5, help="the driver's request timeout (s)")
    args = parser.parse_args()
    r = soak(args.steps, args.every, args.seed, args.timeout)
    print(f"soak over Modbus TCP, seed {args.seed}, a fault every {args.every} ticks on average")
    for key in ("steps", "recorded", "lost_or_repeated", "consecutive", "finite", "ticks", "faults_total", "faults",
                "requests", "retries", "wall_time_s", "stopped", "peak_displacement_mm", "run_file"):
        print(f"{key:<18} {r[key]}")


if __name__ == "__main__":
    main()
