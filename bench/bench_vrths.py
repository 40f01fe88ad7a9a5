"""The vRTHS benchmark (Silva et al. 2020): J1-J9 per case and controller, and the speed of the
RTHS loop against real time, with numba and with the pure-Python loop.

Nominal plant by default; --perturbed K --seed S adds the mean and worst over K perturbed plants.
Prints tables; asserts nothing.

    python bench/bench_vrths.py [--perturbed 20 --seed 7] [--data FOLDER] [--json]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from hsio.commands.bench import default_data_folder
from hsio.rths import benchmark, controllers, evaluate, plant
from hsio.rths.jit import HAVE_NUMBA


def speed(bm, use_numba: bool, seconds: float | None) -> dict:
    """x real time of the loop alone (the reference model and criteria are not counted), best of
    three runs (the machine is shared: the best run is the loop's own speed)."""
    out = {}
    nom = plant.nominal(bm.data)
    for name in controllers.NAMES:
        evaluate.run_one(bm, 1, name, nom, use_numba=use_numba, duration=0.5)  # compile / warm up
        r = min((evaluate.run_one(bm, 1, name, nom, use_numba=use_numba, duration=seconds) for _ in range(3)),
                key=lambda r: r.seconds)
        out[name] = {"simulated_s": r.simulated_s, "loop_s": r.seconds, "x_real_time": r.real_time_factor}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=None)
    ap.add_argument("--perturbed", type=int, default=0)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--python-seconds", type=float, default=5.0, help="record length for the pure-Python timing")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    for bad, message in ((not 0 <= args.perturbed <= 1000, f"--perturbed {args.perturbed}: give 0 to 1000 plants"),
                         (args.seed < 0, f"--seed {args.seed}: give a seed of 0 or more"),
                         (not 0.5 <= args.python_seconds <= 1000.0,  # also refuses nan
                          f"--python-seconds {args.python_seconds:g}: give 0.5 to 1000 s")):
        if bad:
            ap.error(message)
    folder = args.data or default_data_folder()
    if not (folder / "benchmark.json").is_file() or not (folder / "elcentro_vrths.csv").is_file():
        ap.error(f"--data {folder}: benchmark.json and elcentro_vrths.csv not found there")
    try:
        bm = benchmark.load(str(folder))
    except (ValueError, KeyError, TypeError, IndexError, OSError) as exc:  # as `hsio bench vrths` refuses them
        ap.error(f"--data {folder}: benchmark.json or elcentro_vrths.csv cannot be read: {exc}")
    available = benchmark.moving_span(bm)[1]
    if args.python_seconds > available:
        ap.error(f"--python-seconds {args.python_seconds:g}: the record has {available:g} s from its first motion")
    try:
        plant.perturbed(bm.data, args.seed, args.perturbed)  # the plants the runs will draw
    except ValueError as exc:
        ap.error(f"--perturbed {args.perturbed}: {folder / 'benchmark.json'}: {exc}")
    t0 = time.perf_counter()
    rows = []
    for case in bm.cases:
        for name in controllers.NAMES:
            row = evaluate.evaluate(bm, case, name)
            if args.perturbed:
                p = evaluate.evaluate(bm, case, name, args.perturbed, args.seed)
                row["perturbed"] = {"mean": p["mean"], "worst": p["worst"], "runs": p["runs"], "seed": args.seed}
            rows.append(row)
    report = {"rows": rows, "table3": {c: bm.table3(c) for c in bm.cases},
              "speed_numba": speed(bm, True, None) if HAVE_NUMBA else None,
              "speed_python": speed(bm, False, args.python_seconds), "wall_s": time.perf_counter() - t0}
    if args.json:
        print(json.dumps(report, indent=1))
        return
    print("vRTHS benchmark, El Centro x 0.4, nominal plant: J1 (ms), J2-J9 (%)")
    print(f"{'case':>4} {'controller':<10} " + " ".join(f"{f'J{i}':>6}" for i in range(1, 10)))
    for row in rows:
        print(f"{row['case']:>4} {row['controller']:<10} " + " ".join(f"{j:6.2f}" for j in row["J"]))
        if row["controller"] == "pi-lead" and bm.table3(row["case"]) is not None:
            print(f"{'':>4} {'Table 3':<10} " + " ".join(f"{j:6.2f}" for j in bm.table3(row["case"])))
    if args.perturbed:
        print(f"\nJ2 and J4 (%) over {args.perturbed} perturbed plants (seed {args.seed}): mean / worst")
        print(f"{'case':>4} {'controller':<10} {'J2 nom':>7} {'J2 mean':>8} {'J2 worst':>9} {'J4 nom':>7} {'J4 mean':>8} {'J4 worst':>9}")
        for row in rows:
            p = row["perturbed"]
            print(f"{row['case']:>4} {row['controller']:<10} {row['J'][1]:7.2f} {p['mean'][1]:8.2f} {p['worst'][1]:9.2f} "
                  f"{row['J'][3]:7.2f} {p['mean'][3]:8.2f} {p['worst'][3]:9.2f}")
    print("\nloop speed, case 1 (x real time = simulated seconds / wall seconds of the loop)")
    for label, key in (("numba", "speed_numba"), ("pure Python", "speed_python")):
        sp = report[key]
        if sp is None:
            print(f"  {label:<12} numba is not installed")
            continue
        print(f"  {label:<12} " + ", ".join(f"{n} x{v['x_real_time']:.0f} ({v['simulated_s']:.1f} s in {v['loop_s']:.2f} s)"
                                          for n, v in sp.items()))


if __name__ == "__main__":
    main()
