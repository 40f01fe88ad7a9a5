"""`hsio study`: parametric studies of the integrators (docs/method.md sections 3 and 5)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import click
from click.core import ParameterSource

from hsio.commands import PlotFile, output_error
from hsio.errors import HsioError


def _plot(plot, rows, path: str, command: str) -> None:
    """Draw ``rows`` to ``path``; a path that cannot be written ends the command with status 2."""
    try:
        plot(rows, path)
    except OSError as exc:
        click.echo(f"{command}: error: {output_error(exc, 'the plot')}", err=True)
        sys.exit(2)


@click.group()
def study() -> None:
    """Parametric studies of the integrators."""


@study.command("fc-vs-dc")
@click.option("--json", "as_json", is_flag=True, help="Print the rows as JSON on stdout.")
@click.option("--plot", "plot_path", type=PlotFile(),
              help="Write Er against theta to this file (.png unless its extension names another format).")
@click.option("--thetas", "n_theta", default=15, show_default=True, type=click.IntRange(2, 200),
              help="Number of theta values, log-spaced from 0.2 to 5.0.")
def fc_vs_dc(as_json: bool, plot_path: str | None, n_theta: int) -> None:
    """Energy error Er (eq. 14) of FC and DC on a Menegotto-Pinto SDOF (the paper's Figure 12)."""
    from hsio import study as study_mod

    try:
        rows = study_mod.fc_vs_dc(study_mod.thetas(n_theta))
    except HsioError as exc:
        click.echo(f"hsio study fc-vs-dc: error: {exc}", err=True)
        sys.exit(2)
    if plot_path:
        _plot(study_mod.plot, rows, plot_path, "hsio study fc-vs-dc")
    if as_json:
        click.echo(json.dumps(study_mod.rows_as_dicts(rows), indent=1))
        return
    click.echo(f"{'alpha':>6} {'zeta':>5} {'dt':>6} {'theta':>7} {'Er DC %':>10} {'Er FC %':>10} {'FC-DC (pp)':>11}")
    for r in rows:
        click.echo(f"{r.alpha:6.2f} {r.zeta:5.2f} {r.dt:6.3f} {r.theta:7.3f} {r.er_dc_pct:10.5f} {r.er_fc_pct:10.5f} "
                   f"{r.er_fc_pct - r.er_dc_pct:11.2e}")
    worst = max(abs(r.er_fc_pct - r.er_dc_pct) for r in rows)
    click.echo(f"largest |Er FC - Er DC| = {worst:.2e} percentage points")
    if plot_path:
        click.echo(f"plot: {plot_path}")


# The grid's axes: a specimen's initial stiffness and the instruments' resolutions, each positive
# (a zero resolution has no switching threshold, a stiffness sets the specimen's mass), with the
# upper bounds of the run configuration's switching keys (docs/config.md).
GRID_BOUNDS = {"stiffness": (0.0, 10000.0, "kN/mm"), "resolution": (0.0, 10.0, "mm"),
               "force_resolution": (0.0, 100.0, "kN")}


@study.command("mixed")
@click.option("--json", "as_json", is_flag=True, help="Print the rows as JSON on stdout.")
@click.option("--plot", "plot_path", type=PlotFile(),
              help="Write the error maps to this file (.png unless its extension names another format).")
@click.option("--stiffness", "stiffnesses", multiple=True, type=float, help="k0 of the grid (kN/mm); repeat.")
@click.option("--resolution", "resolutions", multiple=True, type=float, help="Transducer resolution (mm); repeat.")
@click.option("--force-resolution", "force_resolutions", multiple=True, type=float,
              help="Load-cell resolution (kN); repeat.")
@click.option("--duration", default=2.0, show_default=True, type=click.FloatRange(0.1, 60.0),
              help="Record length of the grid runs (s).")
@click.option("--seed", default=None, type=click.IntRange(0, None),
              help="Seed of the grid's synthetic record [default: the study's, 1994].")
@click.option("--structures/--no-structures", default=False, show_default=True,
              help="Also run the shipped structures with every method (4 s records).")
@click.option("--config", "configs", multiple=True, type=click.Path(dir_okay=False),
              help="A run configuration (hsio run's TOML: its structure, record, test rate, emulated "
                   "instruments) to run with every method; repeat.")
@click.option("--grid/--no-grid", "with_grid", default=None,
              help="Run the grid [default: yes, unless --config is given].")
def mixed(as_json, plot_path, stiffnesses, resolutions, force_resolutions, duration, seed, structures, configs,
          with_grid) -> None:
    """HS-vs-NS error of DC, FC and mixed over stiffness x transducer x load-cell resolution, on the
    shipped structures (--structures) and on run configurations of your own (--config)."""
    from hsio import study_mixed as sm

    for option, values, (low, high, unit) in (("--stiffness", stiffnesses, GRID_BOUNDS["stiffness"]),
                                              ("--resolution", resolutions, GRID_BOUNDS["resolution"]),
                                              ("--force-resolution", force_resolutions, GRID_BOUNDS["force_resolution"])):
        for value in values:
            if not low < value <= high:
                raise click.BadParameter(f"{value:g} is out of bounds: it must be above {low:g} and at most "
                                         f"{high:g} {unit}", param_hint=option)
    if with_grid is None:
        with_grid = not configs
    given_duration = click.get_current_context().get_parameter_source("duration") is not ParameterSource.DEFAULT
    grid_options = [name for name, given in (("--stiffness", stiffnesses), ("--resolution", resolutions),
                                             ("--force-resolution", force_resolutions), ("--duration", given_duration),
                                             ("--seed", seed is not None))
                    if given]
    if not with_grid and grid_options:
        raise click.UsageError(f"{', '.join(grid_options)} set the grid, which does not run here (--no-grid, or "
                               "--config without --grid)")
    if not (with_grid or structures or configs):
        raise click.UsageError("--no-grid without --structures or --config runs nothing: give one of them, or "
                               "leave --no-grid out")

    def progress(rows):
        row = rows[0]
        where = "grid" if row.case == "grid" else row.case
        errors = ", ".join(f"{r.method} {r.error_pct:.3g} %" if r.error_pct != float("inf") else f"{r.method} stopped"
                           for r in rows)
        axes = (f" k0 {row.k0_kN_mm:g} kN/mm, du {row.resolution_mm:g} mm, dF {row.force_resolution_kN:g} kN:"
                if row.case == "grid" else ":")
        click.echo(f"  {where}{axes} {errors}", err=True)

    try:
        rows = []
        if with_grid:
            rows += sm.grid(stiffnesses or (7.2, 122.6), resolutions or (0.0025, 0.025),
                            force_resolutions or (0.002, 0.02), duration_s=duration,
                            seed=sm.SEED if seed is None else seed, progress=progress)
        if structures:
            rows += sm.structures(progress=progress)
        names = [Path(path).name for path in configs]
        for path in configs:  # each configuration by its file's name, by its path where two share a name
            rows += sm.configured(path, progress=progress, case=path if names.count(Path(path).name) > 1 else None)
    except HsioError as exc:
        click.echo(f"hsio study mixed: error: {exc}", err=True)
        sys.exit(2)
    if plot_path:
        _plot(sm.plot, rows, plot_path, "hsio study mixed")
    if as_json:
        click.echo(json.dumps({"rows": sm.rows_as_dicts(rows),
                               "winners": [{"case": k[0], "k0_kN_mm": k[1], "resolution_mm": k[2],
                                            "force_resolution_kN": k[3], **v} for k, v in sm.winners(rows).items()]},
                              indent=1))
        return
    click.echo(f"{'case':>20} {'k0':>7} {'du mm':>7} {'dF kN':>7} {'method':>14} {'error %':>9} {'switches':>8} "
               f"{'not conv':>8} {'FC %':>5}")
    for r in rows:
        click.echo(f"{r.case:>20} {r.k0_kN_mm:7.4g} {r.resolution_mm:7.4f} {r.force_resolution_kN:7.3f} {r.method:>14} "
                   f"{r.error_pct:9.3f} {r.switches:8d} {r.not_converged_steps:8d} {100 * r.fc_fraction:5.0f}")
    for r in rows:
        if r.stopped:
            click.echo(f"stopped: {r.case}, k0 {r.k0_kN_mm:g} kN/mm, du {r.resolution_mm:g} mm, dF "
                       f"{r.force_resolution_kN:g} kN, {r.method}: {r.stopped}")
    if plot_path:
        click.echo(f"plot: {plot_path}")
