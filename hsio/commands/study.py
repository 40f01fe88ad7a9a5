"""`hsio study`: parametric studies of the integrators (METHOD.md section 3)."""

from __future__ import annotations

import json
import sys

import click

from hsio.errors import HsioError


@click.group()
def study() -> None:
    """Parametric studies of the integrators."""


@study.command("fc-vs-dc")
@click.option("--json", "as_json", is_flag=True, help="Print the rows as JSON on stdout.")
@click.option("--plot", "plot_path", type=click.Path(dir_okay=False), help="Write Er against theta to this PNG.")
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
        study_mod.plot(rows, plot_path)
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
