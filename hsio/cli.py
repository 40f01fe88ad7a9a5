"""The `hsio` command."""

from __future__ import annotations

import importlib
import json
import sys

import click

from hsio.errors import HsioError


class _Progress:
    """A tqdm bar on a terminal, nothing otherwise."""

    def __init__(self, total: int, desc: str):
        from tqdm import tqdm

        self.bar = tqdm(total=total, desc=desc, unit="step", disable=None, file=sys.stderr, leave=False)

    def __call__(self, n: int) -> None:
        self.bar.update(n)

    def close(self) -> None:
        self.bar.close()


# Subcommands that live in their own modules, imported only when used: name -> "module:function".
LAZY_COMMANDS: dict[str, str] = {
    "bench": "hsio.commands.bench:bench",
    "calibrate": "hsio.commands.calibrate:calibrate",
    "diagnose": "hsio.commands.diagnose:diagnose",
    "emulate": "hsio.commands.emulate:emulate",
    "probe": "hsio.commands.probe:probe",
    "serve": "hsio.commands.serve:serve",
    "study": "hsio.commands.study:study",
}


class LazyGroup(click.Group):
    """A click group that imports a subcommand's module only when that subcommand runs."""

    def list_commands(self, ctx):
        return sorted([*super().list_commands(ctx), *LAZY_COMMANDS])

    def get_command(self, ctx, name):
        if name in LAZY_COMMANDS:
            module_name, _, attr = LAZY_COMMANDS[name].partition(":")
            return getattr(importlib.import_module(module_name), attr)
        return super().get_command(ctx, name)


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="hsio")
def main() -> None:
    """hsio: hybrid simulation of structures on real or emulated servo-hydraulic actuators."""


@main.command()
@click.argument("config_file", required=False, type=click.Path(dir_okay=False))
@click.option("--out", "out_dir", default="runs/latest", show_default=True, type=click.Path(file_okay=False),
              help="Folder for run.sqlite, summary.json and the plots.")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON on stdout.")
def run(config_file: str | None, out_dir: str, as_json: bool) -> None:
    """Run a hybrid simulation (default: the validation structure on emulated actuators)."""
    from hsio import config as config_mod
    from hsio import runner
    from hsio.experiment import ExperimentStopped, excitation

    try:
        cfg = config_mod.load(config_file)
        structure = runner.load_run_structure(cfg)
        ground = runner.build_record(cfg, structure)
        steps = len(excitation(structure, ground)[0]) - 1
        progress = _Progress(steps, f"HS {structure.name}")
        try:
            summary = runner.run(cfg, out_dir, progress, ground=ground)
        finally:
            progress.close()
    except ExperimentStopped as exc:
        click.echo(f"hsio run: {exc}", err=True)
        click.echo(f"hsio run: recorded steps are in {out_dir}/run.sqlite", err=True)
        sys.exit(3)
    except HsioError as exc:
        click.echo(f"hsio run: error: {exc}", err=True)
        sys.exit(2)
    if as_json:
        click.echo(json.dumps(summary, indent=2))
    else:
        _print_summary(summary)


def _print_summary(s: dict) -> None:
    click.echo(f"structure      {s['structure']}  ({s['steps']} steps of {s['dt']} s, TR = {s['test_rate']:g})")
    click.echo(f"record         {s['record']}")
    click.echo(f"hardware       {s['hardware']} ({s['clock']})")
    for k, name in enumerate(s["dof"]):
        ns = s.get("ns_peak_displacement_mm")
        line = f"peak {name:<9} HS {s['peak_displacement_mm'][k]:8.3f} mm"
        if ns:
            line += f"   NS {ns[k]:8.3f} mm   max |HS-NS| {s['max_error_pct_per_dof'][k]:.3f} % of peak"
        click.echo(line)
    if "max_error_pct" in s:
        click.echo(f"max error      {s['max_error_pct']:.3f} % (HS vs NS)")
    click.echo(f"tracking RMS   {', '.join(f'{x:.4f}' for x in s['rms_tracking_error_mm'])} mm")
    comp = s.get("compensation", {})
    if comp.get("mode", "off") != "off":
        used = ", ".join(f"{n} a = {c['a_mm_s']:.3g} mm/s, b d_max = {c['lag_s'] * 1e3:.1f} ms"
                         for n, c in comp["actuators"].items() if c["enabled"])
        click.echo(f"compensation   {comp['mode']} ({comp['form']}): {used}")
    if "switches" in s:
        click.echo(f"method         {s['method']}: {s['switches']} switches, FC in "
                   f"{', '.join(f'{x * 100:.0f} %' for x in s['fc_step_fraction'])} of steps, "
                   f"{s['iterations_per_step_mean']:.2f} commands per step, "
                   f"{s['nonconverged_steps']} steps at j_max without convergence")
    click.echo(f"wall time      {s['wall_time_s']:.1f} s (the lab would take {s['test_time_s']:.1f} s)")
    click.echo(f"record file    {s['run_file']}")
    for p in s.get("plots", []):
        click.echo(f"plot           {p}")


if __name__ == "__main__":
    main()
