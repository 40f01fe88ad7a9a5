"""`hsio bench`: benchmarks of the field, run on hsio's models.

`hsio bench vrths` runs the virtual real-time hybrid simulation benchmark of Silva et al. (2020):
the four partitioning cases with a tracking controller on the nominal control plant, or on K
perturbed plants (mean and worst of J1-J9), and prints J1-J9 per case and controller.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import click

J_HEADER = " ".join(f"{f'J{i}':>6}" for i in range(1, 10))


def default_data_folder() -> Path:
    """HSIO_VRTHS_DATA, else shared/data/vrths beside the repository."""
    env = os.environ.get("HSIO_VRTHS_DATA")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[2].parent / "shared" / "data" / "vrths"


@click.group()
def bench() -> None:
    """Benchmarks of the field on hsio's models."""


@bench.command("vrths")
@click.option("--case", "case", type=click.IntRange(1, 4), help="Partitioning case 1-4 (default: all four).")
@click.option("--controller", "controller", default="all", show_default=True,
              type=click.Choice(["all", "pi-lead", "ats", "amb"]),
              help="pi-lead: the benchmark's sample controller; ats: adaptive time series (Chae et al. 2013); "
                   "amb: hsio's adaptive model-based compensator.")
@click.option("--perturbed", "perturbed", default=0, show_default=True, type=click.IntRange(0, 1000),
              help="Run on K perturbed plants (Table 2's uncertainty) and report the mean and worst.")
@click.option("--seed", "seed", type=click.IntRange(0, None), help="Seed of the perturbed plants (needs --perturbed).")
@click.option("--data", "data", type=click.Path(file_okay=False), help="Folder with benchmark.json and "
              "elcentro_vrths.csv (default: $HSIO_VRTHS_DATA or shared/data/vrths beside the repository).")
@click.option("--duration", "duration", type=click.FloatRange(0.5, None), help="Only the first seconds of the record.")
@click.option("--no-numba", "no_numba", is_flag=True, help="Run the pure-Python loop even if numba is installed.")
@click.option("--json", "as_json", is_flag=True, help="Print the results as JSON on stdout.")
def vrths(case, controller, perturbed, seed, data, duration, no_numba, as_json) -> None:
    """J1-J9 of the vRTHS benchmark (Silva et al. 2020) per case and controller."""
    from hsio.rths import benchmark, controllers, evaluate, loop
    from hsio.rths import plant as plant_mod

    if seed is not None and perturbed == 0:
        raise click.UsageError("--seed chooses the perturbed plants: give --perturbed K too")
    folder = Path(data) if data else default_data_folder()
    source = "--data" if data else ("$HSIO_VRTHS_DATA (or --data)" if os.environ.get("HSIO_VRTHS_DATA")
                                    else "--data (default: shared/data/vrths beside the repository)")
    if not (folder / "benchmark.json").is_file() or not (folder / "elcentro_vrths.csv").is_file():
        raise click.BadParameter(f"{folder}: benchmark.json and elcentro_vrths.csv not found there", param_hint=source)
    try:
        bm = benchmark.load(str(folder))
    except (ValueError, KeyError, TypeError, IndexError, OSError) as exc:  # JSONDecodeError is a ValueError
        raise click.BadParameter(f"{folder}: benchmark.json or elcentro_vrths.csv cannot be read: {exc}",
                                 param_hint="--data") from None
    if duration is not None:
        available = benchmark.moving_span(bm)[1]
        if duration > available + 0.5 / benchmark.FS:  # a cut, never a silent clamp
            raise click.BadParameter(f"{duration:g} s is longer than the record ({available:g} s from the first "
                                     "motion); leave --duration out to run the whole record", param_hint="--duration")
    if case and case not in bm.cases:
        raise click.BadParameter(f"{folder / 'benchmark.json'} has cases {bm.cases}", param_hint="--case")
    cases = [case] if case else bm.cases
    names = list(controllers.NAMES) if controller == "all" else [controller]
    use_numba = False if no_numba else None
    try:
        plant_mod.perturbed(bm.data, seed or 0, perturbed)  # the plants the runs will draw
    except ValueError as exc:
        raise click.BadParameter(f"{folder / 'benchmark.json'}: {exc}", param_hint="--perturbed") from None
    try:
        rows = [evaluate.evaluate(bm, c, name, perturbed, seed or 0, use_numba, duration) for c in cases for name in names]
    except loop.NonFiniteCommandError as exc:
        click.echo(f"Error: {exc}", err=True)
        raise SystemExit(3) from None
    if as_json:
        click.echo(json.dumps(rows, indent=1))
        return
    click.echo(f"{'case':>4} {'controller':<8} {'':<6} {J_HEADER}  {'x real time':>11}")
    for row in rows:
        kinds = [("", row["J"])] if "J" in row else [("mean", row["mean"]), ("worst", row["worst"])]
        for kind, J in kinds:
            values = " ".join(f"{j:6.2f}" for j in J)
            click.echo(f"{row['case']:>4} {row['controller']:<8} {kind:<6} {values}  {row['x_real_time']:11.0f}")
        if "J" in row and perturbed == 0 and duration is None and row["controller"] == "pi-lead" \
                and bm.table3(row["case"]) is not None:
            t3 = " ".join(f"{j:6.2f}" for j in bm.table3(row["case"]))
            click.echo(f"{'':>4} {'Table 3':<8} {'':<6} {t3}")
    table3 = bm.data.get("table3_sample_controller_elcentro")
    held = isinstance(table3, dict) and any(str(row["case"]) in table3 for row in rows)  # else there is none to show
    if perturbed == 0 and duration is None and "pi-lead" in names and held and not bm.is_table3_record():
        click.echo("Table 3 not shown: it is of the benchmark's El Centro record, and this record differs "
                   f"({bm.record_t.size} samples, peak {float(abs(bm.record_a).max()):.4g} m/s^2)")
    for row in rows:
        if row["limits_reached"]:
            click.echo(f"case {row['case']} {row['controller']}: " + "; ".join(row["limits_reached"]))
