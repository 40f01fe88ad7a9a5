"""Benchmark: what the live monitor costs (docs/monitor.md section 4).

1. The step time of a lockstep run (the default structure and record, 1,000 steps) without the
   monitor, with ``--monitor`` serving nobody, and with a headless chromium following the page
   throughout (when installed; at nice 10, as `hsio run --monitor` runs its server, so that on a
   machine with fewer free cores than processes the loop gets the processor first). Runs
   alternate; the medians are compared.
2. The page with 20,000 steps recorded: the server's time to build a new tab's document and its
   size, then per update (ten new steps) the bytes sent and the server's time; with chromium, the
   time for a browser to load the page and draw the record.
3. The page server's memory for a long run: twelve channels, 100,000 steps read from the record
   (what the feed holds once it has read them all, and its peak while reading).

Run: .venv/bin/python bench/bench_monitor.py [--repeat 2]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}
RUN = "[record]\nduration_s = 10.0\n[output]\nplots = false\n[safety]\nkeys = false\n"


def one_run(folder: Path, monitor: bool, with_browser: bool) -> float:
    """Wall time per step (ms) of one `hsio run` (the loop's own wall time, from its summary)."""
    cmd = [sys.executable, "-m", "hsio.cli", "run", str(folder / "run.toml"), "--out", str(folder / "o"), "--json"]
    if monitor:
        cmd += ["--monitor", "--monitor-port", "0"]
    proc = subprocess.Popen(cmd, env=ENV, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    err: list[str] = []
    reader = threading.Thread(target=lambda: err.extend(proc.stderr), daemon=True)
    reader.start()
    browser = None
    try:
        if monitor and with_browser:
            from hsio.monitor.browser import Browser

            deadline = time.monotonic() + 60
            while not any("monitor at" in line for line in err) and time.monotonic() < deadline:
                time.sleep(0.05)
            url = next(line for line in err if "monitor at" in line).rpartition(" at ")[2].strip()
            browser = Browser(nice=10)
            browser.driver.get(url)
        out, _ = proc.communicate(timeout=900)
    finally:
        if browser is not None:
            browser.close()
        if proc.poll() is None:
            proc.kill()
    reader.join(timeout=5)
    if proc.returncode != 0:
        raise SystemExit(f"the run failed: {''.join(err)[-2000:]}")
    summary = json.loads(out)
    return 1e3 * summary["wall_time_s"] / summary["steps"]


def loop_cost(repeat: int, with_browser: bool) -> None:
    kinds = {"without the monitor": (False, False), "with the monitor, no page open": (True, False)}
    if with_browser:
        kinds["with the monitor, chromium following"] = (True, True)
    times: dict[str, list[float]] = {k: [] for k in kinds}
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(repeat):
            for j, (label, (monitor, browse)) in enumerate(kinds.items()):
                folder = Path(tmp) / f"{i}-{j}"
                folder.mkdir()
                (folder / "run.toml").write_text(RUN)
                times[label].append(one_run(folder, monitor, browse))
    plain = statistics.median(times["without the monitor"])
    for label, values in times.items():
        m = statistics.median(values)
        extra = "" if label == "without the monitor" else f"  overhead {100 * (m / plain - 1):+5.1f} % (target: under 5 %)"
        print(f"lockstep step time {label:<37} {m:7.3f} ms  (runs: {', '.join(f'{x:.3f}' for x in values)}){extra}")


def synthetic_record(folder: Path, steps: int):
    """A record of ``steps`` steps of a two-channel sine test, written in bulk."""
    from hsio.recording import Recorder

    meta = {"structure": "validation", "record": "sine", "dt": 0.01, "test_rate": 20.0,
            "config": {"structure": {"name": "validation", "file": ""}, "safety": {}},
            "dry_run": {"limits": {"stroke_mm": 254.0, "force_kN": 250.0, "velocity_mm_s": 500.0}}}
    rec = Recorder(folder / "run.sqlite", ["C1", "C2"], ["C1", "C2"], meta)
    rec.db.execute("PRAGMA synchronous=OFF")
    t = np.arange(steps + 1) * 0.01
    u = np.column_stack([10 * np.sin(2 * np.pi * 0.5 * t), 8 * np.sin(2 * np.pi * 0.7 * t)])
    rec.write_ns(t, u)
    rows = [[k, t[k], *[x for j in range(2) for x in (u[k, j], 0.0, 0.0, u[k, j], 0.5 * u[k, j])],
             "displacement", "displacement", *[x for j in range(2) for x in (u[k, j], u[k, j], u[k, j], 0.5 * u[k, j])],
             0, ""] for k in range(1, steps + 1)]
    rec.db.executemany(rec._insert_step, rows)
    rec.db.commit()
    return rec


def wire_bytes(msg) -> int:
    return (len(msg.header_json) + len(msg.metadata_json) + len(msg.content_json)
            + sum(len(b.to_bytes()) for b in msg.buffers))


def page_cost(steps: int, with_browser: bool) -> None:
    from bokeh.document import Document
    from bokeh.protocol import Protocol

    from hsio.monitor.feed import RecordFeed
    from hsio.monitor.operator import Operator
    from hsio.monitor.page import MonitorPage

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        rec = synthetic_record(folder, steps)
        feed = RecordFeed(folder)
        doc = Document()
        t0 = time.perf_counter()
        page = MonitorPage(doc, feed, Operator(folder))
        build = time.perf_counter() - t0
        first = wire_bytes(Protocol().create("PULL-DOC-REPLY", "bench", doc))
        print(f"page with {steps:,} steps recorded: a new tab's document {first / 1e3:.0f} kB, built in "
              f"{build * 1e3:.0f} ms; {len(page.steps.data['t'])} points per history (every {page.decimation.stride}th step)")
        events: list = []
        doc.on_change(events.append)
        sizes, times = [], []
        for i in range(20):
            for k in range(steps + 1 + 10 * i, steps + 11 + 10 * i):
                v = [np.sin(k), np.cos(k)]
                rec.write_step(k, k * 0.01, v, [0, 0], [0, 0], v, [0, 0], ["displacement"] * 2, v, v, v, v)
            events.clear()
            page._plotted = 0.0
            feed._last_poll = 0.0
            t0 = time.perf_counter()
            page.update()
            times.append(time.perf_counter() - t0)
            sizes.append(wire_bytes(Protocol().create("PATCH-DOC", events)) if events else 0)
        print(f"per update (10 new steps): {statistics.median(sizes) / 1e3:.1f} kB sent (largest "
              f"{max(sizes) / 1e3:.1f} kB, with the spectrum), {statistics.median(times) * 1e3:.1f} ms on the server")
        rec.close()
        feed.close()
        if with_browser:
            from hsio.monitor.browser import Browser

            proc = subprocess.Popen([sys.executable, "-m", "hsio.cli", "monitor", str(folder), "--port", "0"],
                                    env=ENV, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
            try:
                url = proc.stdout.readline().rpartition(" at ")[2].strip()
                with Browser() as b:
                    t0 = time.perf_counter()
                    b.driver.get(url)
                    while not b.model("head", "m.data.step.length ? m.data.step[0] : 0"):
                        time.sleep(0.02)
                    b.driver.execute_async_script("requestAnimationFrame(() => requestAnimationFrame(arguments[0]))")
                    print(f"chromium: page loaded and the record drawn in {time.perf_counter() - t0:.2f} s")
            finally:
                proc.terminate()
                proc.wait(timeout=10)


def long_record(folder: Path, channels: int, steps: int):
    """A record of ``steps`` steps of ``channels`` channels (one DOF each), written in bulk."""
    from hsio.recording import Recorder

    names = [f"C{j + 1}" for j in range(channels)]
    meta = {"structure": "bench", "record": "sine", "dt": 0.01, "test_rate": 20.0, "steps_total": steps,
            "config": {"structure": {"name": "validation", "file": ""}, "safety": {}},
            "dry_run": {"limits": {"stroke_mm": 254.0, "force_kN": 250.0, "velocity_mm_s": 500.0}}}
    rec = Recorder(folder / "run.sqlite", names, names, meta)
    rec.db.execute("PRAGMA synchronous=OFF")
    cols = rec._step_cols
    for start in range(1, steps + 1, 10_000):
        k = np.arange(start, min(start + 10_000, steps + 1))
        rows = []
        for i, name in enumerate(cols):
            if name == "step":
                rows.append(k.tolist())
            elif name == "time_s":
                rows.append((k * 0.01).tolist())
            elif name.startswith("mode_"):
                rows.append(["displacement"] * len(k))
            elif name == "flags":
                rows.append([""] * len(k))
            else:
                rows.append(np.sin(0.001 * k * (1 + i % 7)).tolist())
        rec.db.executemany(rec._insert_step, list(zip(*rows)))
        rec.db.commit()
    return rec


def feed_memory(channels: int, steps: int) -> None:
    import tracemalloc

    from hsio.monitor.feed import RecordFeed
    from hsio.structures import get_structure

    with tempfile.TemporaryDirectory(dir="/dev/shm" if os.path.isdir("/dev/shm") else None) as tmp:
        folder = Path(tmp)
        long_record(folder, channels, steps).close()
        feed = RecordFeed(folder)
        get_structure("validation")  # the modules the feed imports to read the structure: not the feed's memory
        tracemalloc.start()
        try:
            t0 = time.perf_counter()
            while feed.poll(force=True):
                pass
            took = time.perf_counter() - t0
            held, peak = tracemalloc.get_traced_memory()
        finally:
            tracemalloc.stop()
        print(f"page server's feed, {channels} channels x {steps:,} steps read: holds {held / 1e6:.1f} MB "
              f"(peak {peak / 1e6:.1f} MB while reading, {took:.1f} s with tracemalloc)")
        feed.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=2, help="runs of each kind (default 2)")
    parser.add_argument("--memory-only", action="store_true", help="only the page server's memory (part 3)")
    args = parser.parse_args()
    if args.memory_only:
        feed_memory(12, 100_000)
        return
    from hsio.monitor import browser

    reason = browser.missing()
    if reason:
        print(f"no browser: {reason}")
    print(f"machine load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    loop_cost(args.repeat, not reason)
    page_cost(20_000, not reason)
    feed_memory(12, 100_000)


if __name__ == "__main__":
    main()
