"""Benchmark: the cost of the Recorder's checkpoints (docs/safety.md section 1, "Cost of durable
steps") on the default run in lockstep emulation (2000 steps, samples recorded).

Runs it with a checkpoint every CHECKPOINT_S of wall time (the default, 1 s; and 0.1 s) and with
none but those at creation and close, in turn (the order rotated each round), and prints the wall
time of each run, per step. Run: .venv/bin/python bench/bench_checkpoint.py [REPEATS]
"""

from __future__ import annotations

import os
import sys
import tempfile
import time

from hsio import config
from hsio.recording import Recorder
from hsio.runner import run


def main(repeats: int = 2) -> None:
    cfg = config.load(None)
    cfg["output"]["plots"] = False
    cfg["safety"]["keys"] = False
    default = Recorder.CHECKPOINT_S
    settings = [("every 1 s (default)", default), ("every 0.1 s", 0.1), ("at creation and close only", float("inf"))]
    times: dict[str, list[float]] = {label: [] for label, _ in settings}
    with tempfile.TemporaryDirectory() as out:
        for r in range(repeats):
            for label, interval in settings[r % 3:] + settings[:r % 3]:
                Recorder.CHECKPOINT_S = interval
                folder = os.path.join(out, f"{r}-{interval}")
                os.makedirs(folder)
                t0 = time.perf_counter()
                summary = run(cfg, folder)
                times[label].append(time.perf_counter() - t0)
    Recorder.CHECKPOINT_S = default
    print(f"default run, {summary['steps']} steps, samples recorded, {repeats} runs each (in turn)")
    for label, _ in settings:
        ts = times[label]
        print(f"  checkpoint {label:<28} wall {min(ts):6.2f}-{max(ts):6.2f} s  "
              f"per step {1e3 * min(ts) / summary['steps']:5.2f}-{1e3 * max(ts) / summary['steps']:5.2f} ms")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 2)
