"""Benchmark: integration steps per second of the default run in lockstep emulation.

Prints the default configuration's wall time, steps per second, and two ratios: earthquake
time over wall time (how much faster than real time), and lab test time (steps x TR x dt) over
wall time (how much faster than the same test on the lab floor). Also the purely numerical
simulation for reference. Run: .venv/bin/python bench/bench_run.py
"""

from __future__ import annotations

import tempfile
import time

from hsio import config
from hsio.api import run_numerical
from hsio.runner import build_record, run
from hsio.structures import get_structure


def main() -> None:
    cfg = config.load(None)
    cfg["output"]["plots"] = False
    structure = get_structure(cfg["structure"]["name"])
    ground = build_record(cfg, structure)
    t0 = time.perf_counter()
    ns = run_numerical(structure, ground, "alpha_os", cfg["integrator"]["alpha"])
    ns_wall = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as out:
        for keep in (True, False):
            cfg["output"]["samples"] = keep
            t0 = time.perf_counter()
            summary = run(cfg, f"{out}/{'samples' if keep else 'steps'}")  # a new folder per run
            wall = time.perf_counter() - t0
            steps = summary["steps"]
            quake = steps * structure.dt
            lab = quake * cfg["test"]["rate"]
            label = "HS lockstep, recording samples" if keep else "HS lockstep, steps only"
            print(f"{label:<34} {steps} steps  {wall:6.2f} s  {steps / wall:8.0f} steps/s  "
                  f"{quake / wall:5.2f}x real time  {lab / wall:6.1f}x the lab (TR {cfg['test']['rate']:g})  "
                  f"controller ticks/s {steps * round(cfg['test']['rate'] * structure.dt * 1024) / wall:,.0f}")
    print(f"{'NS (same integrator, models)':<34} {ns.steps} steps  {ns_wall:6.2f} s  {ns.steps / ns_wall:8.0f} steps/s")


if __name__ == "__main__":
    main()
