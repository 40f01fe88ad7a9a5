"""The `hsio` command."""

from __future__ import annotations

import contextlib
import importlib
import json
import os
import signal
import sys
from pathlib import Path

import click

from hsio.commands import RegularFile, refuse_repeated_options
from hsio.errors import ConfigError, HsioError


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
    "monitor": "hsio.commands.monitor:monitor",
    "probe": "hsio.commands.probe:probe",
    "serve": "hsio.commands.serve:serve",
    "study": "hsio.commands.study:study",
}


# Commands that answer a SIGINT noted while the program started (hsio.entry) as their own stop.
ANSWER_SIGINT_THEMSELVES = ("run", "resume", "serve", "emulate")


class LazyGroup(click.Group):
    """A click group that imports a subcommand's module only when that subcommand runs."""

    def list_commands(self, ctx):
        return sorted([*super().list_commands(ctx), *LAZY_COMMANDS])

    def get_command(self, ctx, name):
        if name in LAZY_COMMANDS:
            module_name, _, attr = LAZY_COMMANDS[name].partition(":")
            command = getattr(importlib.import_module(module_name), attr)
        else:
            command = super().get_command(ctx, name)
        return refuse_repeated_options(command) if command is not None else None


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="hsio")
@click.pass_context
def main(ctx: click.Context) -> None:
    """hsio: hybrid simulation of structures on real or emulated servo-hydraulic actuators."""
    if ctx.invoked_subcommand not in ANSWER_SIGINT_THEMSELVES:
        from hsio.entry import release

        release()


@main.command()
@click.argument("config_file", required=False, type=RegularFile())
@click.option("--out", "out_dir", default=None, type=click.Path(file_okay=False),
              help="Folder for run.sqlite, summary.json and the plots; refused if it holds a record. "
                   "Default: a new numbered folder runs/<structure>/run-NNNN.")
@click.option("--specimen", "specimen_dir", default=None, type=click.Path(file_okay=False),
              help="The specimen folder whose ledger lists this run (else [specimen] folder / id).")
@click.option("--override-dry-run", is_flag=True,
              help="Run even if the dry run predicts a limit is exceeded (recorded in the run and the ledger).")
@click.option("--json", "as_json", is_flag=True,
              help="Print the summary as JSON on stdout, also when the run is refused or stops (what summary.json "
                   "holds; where none was written, the error).")
@click.option("--monitor", "with_monitor", is_flag=True,
              help="Serve the live monitor page during the run (docs/monitor.md).")
@click.option("--monitor-port", default=8765, show_default=True, type=click.IntRange(0, 65535),
              help="Port of the monitor page (0: any free port).")
@click.option("--monitor-host", default="127.0.0.1", show_default=True,
              help="Address of the monitor page; any but the loopback requires the token it prints.")
def run(config_file: str | None, out_dir: str | None, specimen_dir: str | None, override_dry_run: bool,
        as_json: bool, with_monitor: bool, monitor_port: int, monitor_host: str) -> None:
    """Run a hybrid simulation (default: the validation structure on emulated actuators).

    Keys p (pause), r (resume), s (stop) on a terminal; the control socket in the run folder
    (docs/safety.md). Exit status: 0 done, 2 bad input or refused by the dry run, 3 stopped by a
    limit or fault, 4 stopped by an interlock, 5 stopped by the operator or a signal.
    """
    if not with_monitor:  # a port or address given for a page that would never be served
        given = [f"--{name.replace('_', '-')}" for name in ("monitor_port", "monitor_host")
                 if click.get_current_context().get_parameter_source(name) is click.core.ParameterSource.COMMANDLINE]
        if given:
            raise click.UsageError(f"{' and '.join(given)} set the monitor's page, which only --monitor serves: "
                                   "add --monitor")
    from hsio import config as config_mod
    from hsio import runner
    from hsio.experiment import ExperimentStopped, excitation
    from hsio.safety.control import RunControl, stop_on_signals
    from hsio.safety.status import DryRunRefused, exit_status
    from hsio.safety.terminal import KeyReader

    control = RunControl()
    notify = lambda line: click.echo(f"hsio run: {line}", err=True)  # noqa: E731
    control.listeners.append(notify)
    try:
        with stop_on_signals(control):  # from here a Ctrl-C asks the run to stop, before and during it
            cfg = config_mod.load(config_file)
            if override_dry_run:
                if not cfg["safety"]["dry_run"]:
                    raise ConfigError(f"--override-dry-run: {config_file or 'the configuration'} turns the dry run "
                                      f"off ([safety] dry_run = false): there is no refusal to override")
                cfg["safety"]["override"] = True
            structure = runner.load_run_structure(cfg)
            runner.check_run_method(cfg, structure)
            runner.check_site(cfg, structure)  # before any folder: a typing error leaves none
            ground = runner.build_record(cfg, structure)
            steps = len(excitation(structure, ground)[0]) - 1
            with contextlib.ExitStack() as cleanup:  # closed in reverse: the bar, the keys, then the page
                control.check_stop()  # a Ctrl-C while hsio started: no folder, no page
                if with_monitor:  # the page reads the record of the run's folder from its own process
                    from hsio.monitor.server import MonitorProcess

                    runner.fingerprints(cfg)  # an input file that cannot be read: refused before the folder too
                    created = out_dir is None or not os.path.exists(out_dir)  # a name too long: run_folder names it
                    out_dir = runner.run_folder(cfg, structure, out_dir)
                    try:
                        page = cleanup.enter_context(MonitorProcess(out_dir, monitor_host, monitor_port))
                    except ConfigError:  # no page, no run: the folder keeps nothing (its number stays free)
                        _discard_page_log(out_dir, created)
                        raise
                    click.echo(f"hsio run: monitor at {page.url}", err=True)
                if cfg["safety"]["keys"]:
                    cleanup.callback(KeyReader(control, notify).close)
                progress = _Progress(steps, f"HS {structure.name}")
                cleanup.callback(progress.close)
                try:
                    summary = runner.run(cfg, out_dir, progress, ground=ground, control=control,
                                         specimen_dir=specimen_dir, checked=True,
                                         notify=notify if not as_json else (lambda line: None))
                except HsioError as exc:
                    if not (with_monitor and hasattr(exc, "not_begun")):
                        raise
                    cleanup.close()  # the page first: it writes its log in the folder
                    _discard_page_log(out_dir, created)
                    left = "no run folder was left" if not Path(out_dir).exists() else "no record was left in it"
                    raise ConfigError(f"{exc.not_begun} ({out_dir}: {left})") from None
    except DryRunRefused as exc:  # from the present state, the hardware is open: its hold is told too
        click.echo(f"hsio run: {getattr(exc, 'stop_message', None) or exc}", err=True)
        _where(exc)
        if as_json:
            click.echo(json.dumps(_summary_written(exc, 2), indent=2))
        sys.exit(2)
    except (ExperimentStopped, KeyboardInterrupt, HsioError) as exc:
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # the run has held and closed: report it whole
        status = exit_status(exc)
        if isinstance(exc, ExperimentStopped) or status != 2:
            click.echo(f"hsio run: {getattr(exc, 'stop_message', None) or str(exc) or 'interrupted (Ctrl-C)'}",
                       err=True)
        else:
            click.echo(f"hsio run: error: {exc}", err=True)
        _where(exc)
        if as_json:
            click.echo(json.dumps(_summary_written(exc, status), indent=2))
        sys.exit(status)
    if as_json:
        click.echo(json.dumps(summary, indent=2))
    else:
        _print_summary(summary)


@main.command()
@click.argument("run_dir", type=click.Path(file_okay=False, exists=True))
@click.option("--max-gap", "max_gap_mm", type=click.FloatRange(0.0, 1000.0, min_open=True), default=1.0,
              show_default=True, metavar="MM",
              help="Refuse to go on where an actuator stands farther than this from the record's last step (mm).")
def resume(run_dir: str, max_gap_mm: float) -> None:
    """Continue a run interrupted by a crash, a kill or a power loss, from its last committed step,
    into the same record and on the same hardware (docs/safety.md). Exit statuses as for run."""
    from hsio.experiment import ExperimentStopped
    from hsio.safety.control import RunControl
    from hsio.safety.resume import resume as resume_run
    from hsio.safety.status import exit_status
    from hsio.safety.terminal import KeyReader

    control = RunControl()
    notify = lambda line: click.echo(f"hsio resume: {line}", err=True)  # noqa: E731
    control.listeners.append(notify)
    try:
        summary = resume_run(run_dir, control=control, notify=notify, max_gap_mm=max_gap_mm,
                             keys=lambda control: KeyReader(control, notify))
    except (ExperimentStopped, KeyboardInterrupt, HsioError) as exc:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        status = exit_status(exc)
        told = getattr(exc, "stop_message", None) or str(exc) or "interrupted"
        click.echo(f"hsio resume: {'error: ' if status == 2 else ''}{told}", err=True)
        sys.exit(status)
    click.echo(f"resumed from step {summary['resumed_from']}: {summary['steps']} steps in {run_dir}/run.sqlite")


def _summary_written(exc: BaseException, status: int) -> dict:
    """What `hsio run --json` prints for a run that did not finish: the summary.json the run wrote
    in its folder, or, where it wrote none (bad input before the folder), the error and the exit
    status."""
    from hsio.safety.status import outcome_name

    run_dir = getattr(exc, "run_dir", None)
    if run_dir is not None:
        with contextlib.suppress(OSError, ValueError):  # ValueError: not JSON, not text
            return json.loads((Path(run_dir) / "summary.json").read_text())
    error = {"error": str(exc) or "interrupted (Ctrl-C)", "exit_status": status, "outcome": outcome_name(status)}
    return {**error, "run_dir": str(run_dir)} if run_dir is not None else error


def _discard_page_log(out_dir: Path, created: bool) -> None:
    """The monitor's log in a run folder where no run began; the folder too, where hsio made it."""
    from hsio.monitor.server import LOG_FILE

    with contextlib.suppress(OSError):
        (Path(out_dir) / LOG_FILE).unlink()
        if created:
            Path(out_dir).rmdir()  # only if empty


def _where(exc: BaseException) -> None:
    run_dir = getattr(exc, "run_dir", None)
    if run_dir is not None:
        click.echo(f"hsio run: the record is in {run_dir}/run.sqlite", err=True)


@main.command()
@click.argument("config_file", required=False, type=RegularFile())
@click.option("--json", "as_json", is_flag=True, help="Print the dry run's report as JSON on stdout (a bad "
              "configuration: its error, exit_status 2).")
def check(config_file: str | None, as_json: bool) -> None:
    """Dry run: predict the test with NS and the command generator, compare with the limits.

    Nothing opens or moves. Exit status 0 if within the limits less the [safety] margins, 2 if
    the test would be refused (or the configuration is bad).
    """
    from hsio import config as config_mod
    from hsio import runner

    try:
        cfg = config_mod.load(config_file)
        structure = runner.load_run_structure(cfg)
        runner.check_run_method(cfg, structure)
        runner.compensation_stage(cfg, structure)  # refused by check as by run (an unstable eq2, unknown actuators)
        ground = runner.build_record(cfg, structure)
        ns, report = runner.predict(cfg, structure, ground)
        switching = runner.describe_switching(cfg, structure, ns)
    except HsioError as exc:
        click.echo(f"hsio check: error: {exc}", err=True)
        if as_json:  # a reader of stdout gets the error too
            click.echo(json.dumps({"error": str(exc), "exit_status": 2, "refused": True}, indent=2))
        sys.exit(2)
    if as_json:
        click.echo(json.dumps({**report.as_dict(), **({"switching": switching} if switching else {})}, indent=2))
    else:
        click.echo(report.text())
        if switching:
            click.echo(runner.switching_text(switching))
    sys.exit(2 if report.refused else 0)


def _amount(value: float, unit: str, width: int = 0) -> str:
    """A displacement with its unit: mm to the micrometre, rad to the microradian."""
    return f"{value:{width}.3f} mm" if unit == "mm" else f"{value:{width}.6f} {unit}"


def _print_summary(s: dict) -> None:
    click.echo(f"structure      {s['structure']}  ({s['steps']} steps of {s['dt']} s, TR = {s['test_rate']:g})")
    click.echo(f"record         {s['record']}")
    click.echo(f"hardware       {s['hardware']} ({s['clock']})")
    dof_units = s.get("dof_units") or ["mm"] * len(s["dof"])
    for k, name in enumerate(s["dof"]):
        ns = s.get("ns_peak_displacement_mm")
        line = f"peak {name:<9} HS {_amount(s['peak_displacement_mm'][k], dof_units[k], 8)}"
        if ns:
            line += f"   NS {_amount(ns[k], dof_units[k], 8)}   max |HS-NS| {s['max_error_pct_per_dof'][k]:.3f} % of peak"
        click.echo(line)
    if "max_error_pct" in s:
        click.echo(f"max error      {s['max_error_pct']:.3f} % (HS vs NS)")
    rms = s["rms_tracking_error_mm"]
    units = s.get("channel_units") or ["mm"] * len(rms)
    channels = s.get("channels") or [str(k) for k in range(len(rms))]
    click.echo("tracking RMS   " + ", ".join(f"{name} none (no step in displacement control)" if x is None
                                             else f"{name} {x:.4f} mm" if u == "mm" else f"{name} {_amount(x, u)}"
                                             for name, x, u in zip(channels, rms, units)))
    for name, error in s.get("static_hold_error_pct", {}).items():
        click.echo(f"preload {name:<6} held within {error:.3f} % through the record")
    for phase, peaks in s.get("static_ramps", {}).items():
        for name, p in peaks.items():
            click.echo(f"preload {name:<6} {phase.replace('_', ' ')}: peak rod speed {p['peak_speed_mm_s']:.2f} mm/s, "
                       f"peak |stroke| {p['peak_stroke_mm']:.3f} mm (measured)")
    if "outer_loop_iterations" in s:
        loops = s["outer_loop_iterations"]
        click.echo(f"outer loop     {loops['mean']:.2f} corrections a trial on average, at most {loops['max']}")
    comp = s.get("compensation", {})
    if comp.get("mode", "off") != "off":
        used = ", ".join(f"{n} a = {c['a_mm_s']:.3g} mm/s, b d_max = {c['lag_s'] * 1e3:.1f} ms"
                         for n, c in comp["actuators"].items() if c["enabled"])
        click.echo(f"compensation   {comp['mode']} ({comp['form']}): {used}")
    if "switches" in s:
        click.echo(f"method         {s['method']}: {s['switches']} switches, FC in "
                   f"{', '.join(f'{x * 100:.0f} % ({name})' for name, x in zip(channels, s['fc_step_fraction']))} "
                   f"of steps, {s['iterations_per_step_mean']:.2f} commands per step, "
                   f"{s['nonconverged_steps']} steps at j_max without convergence"
                   + (f", {s['guarded_steps']} guarded steps" if s.get("guarded_steps") else ""))
        if s.get("secant_refused") is not None:
            from hsio.integrators.implicit import SECANT_Z

            click.echo(f"FC secant      estimates within {SECANT_Z:g} sigma_k of the secant in use, turned away (eq. 11a): "
                       f"{', '.join(f'{n} ({name})' for name, n in zip(channels, s['secant_refused']))}")
    click.echo(f"wall time      {s['wall_time_s']:.1f} s (the lab would take {s['test_time_s']:.1f} s)")
    click.echo(f"record file    {s['run_file']}")
    if s.get("dry_run_override"):
        click.echo("dry run        overridden by the operator (recorded)")
    for p in s.get("plots", []):
        click.echo(f"plot           {p}")


if __name__ == "__main__":
    main()
