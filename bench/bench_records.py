"""Reading large ground-motion files: wall time and peak memory (tracemalloc: what the reader
allocates, its bytes and arrays included) of :func:`hsio.ground_motion.read_columns` on one column
(accelerations at a given step) and two (time, acceleration), and of :func:`read_at2`, for 2e5 and
2e6 samples (the bound, :data:`MAX_SAMPLES`). ``--by-line`` reads them with the line-by-line (and, for .AT2,
word-by-word) parser alone: the one that names the line of what it refuses, and reads every file
the numpy parser does not.

    PYTHONPATH=. python bench/bench_records.py [--by-line]
"""

from __future__ import annotations

import contextlib
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path
from unittest import mock

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hsio import ground_motion  # noqa: E402


def write_files(folder: Path, n: int) -> dict[str, Path]:
    rng = np.random.default_rng(1)
    accel = rng.standard_normal(n) * 0.1
    t = np.arange(n) * 0.005
    one, two, at2 = folder / f"one_{n}.txt", folder / f"two_{n}.csv", folder / f"rec_{n}.AT2"
    rounded = folder / f"rounded_{n}.csv"  # 400 Hz, times to the millisecond: the rounded-times check reads them
    np.savetxt(rounded, np.column_stack([np.arange(n) / 400, accel]), fmt=["%.3f", "%.6e"], delimiter=",")
    np.savetxt(one, accel, fmt="%.6e", header="acceleration (g) at 0.005 s")
    np.savetxt(two, np.column_stack([t, accel]), fmt=["%.3f", "%.6e"], delimiter=",", header="time,acc",
               comments="")
    with at2.open("w") as f:
        f.write("PEER NGA STRONG MOTION DATABASE RECORD\nbench record\n"
                "ACCELERATION TIME SERIES IN UNITS OF G\n" f"NPTS= {n}, DT= .0050 SEC\n")
        for row in range(0, n, 5):
            f.write("  ".join(f"{v:.7E}" for v in accel[row:row + 5]) + "\n")
    return {"one column": one, "two columns": two, "times rounded": rounded, "AT2": at2}


def measure(read) -> tuple[float, float]:
    """Seconds of one read, and the peak MB allocated by another (tracemalloc slows the first)."""
    t0 = time.perf_counter()
    record = read()
    seconds = time.perf_counter() - t0
    del record
    tracemalloc.start()
    read()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return seconds, peak / 1e6


def main() -> None:
    by_line = "--by-line" in sys.argv
    print("parser:", "line by line" if by_line else "numpy where it can, else line by line")
    with contextlib.ExitStack() as stack:
        tmp = stack.enter_context(tempfile.TemporaryDirectory())
        if by_line:
            stack.enter_context(mock.patch.object(ground_motion, "_rows_at_once", lambda path, data: None))
            stack.enter_context(mock.patch.object(ground_motion, "_values_at_once", lambda data, pos, npts: None))
        for n in (200_000, 2_000_000):
            for kind, path in write_files(Path(tmp), n).items():
                dt_s = 0.005 if kind == "one column" else None
                read = ((lambda p=path: ground_motion.read_at2(p)) if kind == "AT2" else
                        (lambda p=path, dt_s=dt_s: ground_motion.read_columns(p, dt_s=dt_s, units="g")))
                seconds, peak_mb = measure(read)
                print(f"{kind:13s} {n:>9,d} samples, {path.stat().st_size / 1e6:5.1f} MB: {seconds:6.2f} s, "
                      f"peak {peak_mb:6.0f} MB")


if __name__ == "__main__":
    main()
