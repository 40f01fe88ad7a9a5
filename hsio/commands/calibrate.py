"""`hsio calibrate`: fit the hockey stick of docs/method.md eq. 1 to a recorded run (or a CSV file)."""

from __future__ import annotations

import json
import sys

import click

from hsio.commands import PlotFile, output_error
from hsio.errors import HsioError


@click.command()
@click.argument("source", type=click.Path())
@click.option("--json", "as_json", is_flag=True, help="Print {a_mm_s, b_s_mm, lag_s, a_std, b_std, n} as JSON.")
@click.option("--plot", "plot_path", type=PlotFile(),
              help="Draw error against velocity with the fit to this file (.png unless its extension names another format).")
@click.option("--actuator", "actuators", multiple=True, help="Calibrate this actuator only (repeatable; default: all).")
@click.option("--t-d", "t_d", type=float, help="Lab duration of one step (s); default from the run or the CSV times.")
@click.option("--test-rate", type=float, help="CSV only: time_s is record time; t_d = test rate x its step.")
@click.option("--d-max", "d_max", type=float, default=254.0, show_default=True, help="Stroke normalising the error (mm).")
@click.option("--velocity", type=click.Choice(["step", "end"]), default="step", show_default=True,
              help="step: (d_i - d_(i-1)) / t_d as in the paper; end: the velocity at the end of the step.")
def calibrate(source: str, as_json: bool, plot_path: str | None, actuators: tuple, t_d: float | None,
              test_rate: float | None, d_max: float, velocity: str) -> None:
    """Fit a and b of the hockey-stick error model to SOURCE: a run folder, run.sqlite, or a CSV
    file with time_s,command_mm,measured_mm (one row per step)."""
    from hsio.compensation import calibration

    try:
        if not 0.1 <= d_max <= 1e5:
            raise HsioError(f"--d-max is the actuator's stroke in mm, 0.1 to 100000, got {d_max}")
        if t_d is not None and not t_d > 0:
            raise HsioError(f"--t-d must be positive, got {t_d}")
        if test_rate is not None and not test_rate > 0:
            raise HsioError(f"--test-rate must be positive, got {test_rate}")
        cals = calibration.calibrate(source, list(actuators) or None, t_d, test_rate, d_max, 1 if velocity == "step" else 2)
        if plot_path:
            try:
                calibration.plot(plot_path, cals)
            except OSError as exc:
                raise HsioError(output_error(exc, "the plot")) from None
    except HsioError as exc:
        click.echo(f"hsio calibrate: error: {exc}", err=True)
        sys.exit(2)
    for warning in dict.fromkeys(w for c in cals for w in c.warnings):  # a run's warnings once, then each actuator's
        click.echo(f"hsio calibrate: warning: {warning}", err=True)
    if as_json:
        if len(cals) == 1:
            out = cals[0].fit.to_json()
        else:
            out = {c.actuator: c.fit.to_json() for c in cals}
        click.echo(json.dumps(out, indent=2))
        return
    for c in cals:
        f = c.fit
        click.echo(f"actuator   {c.actuator}  ({f.n} steps, t_d = {c.t_d:.4g} s, d_max = {f.d_max_mm:g} mm)")
        click.echo(f"a          {f.a_mm_s:.4g} +/- {f.a_std:.2g} mm/s")
        click.echo(f"b          {f.b_s_mm:.4e} +/- {f.b_std:.2e} s/mm")
        click.echo(f"lag b d_max {f.lag_s * 1e3:.2f} ms")
        click.echo(f"rms resid  {f.rms_residual * f.d_max_mm:.4f} mm")
    if plot_path:
        click.echo(f"plot       {plot_path}")
