"""`hsio diagnose`: replay the actuator model against a measured record, name what it gets wrong,
extend it and measure the gain on held-out data (docs/diagnose.md)."""

from __future__ import annotations

import json
import os
import sys
from typing import Callable, NoReturn, TypeVar

import click

from hsio.commands import RegularFile, output_error
from hsio.errors import HsioError

T = TypeVar("T")
MARGIN_BOUNDS = (1.0, 100.0)  # --margin: the factor by which a cause must divide the held-out error


@click.command()
@click.argument("file", required=False, type=RegularFile(exists=True))
@click.option("--specimen", "specimen_file", default=None, type=RegularFile(exists=True),
              help="Diagnose a specimen from its measured displacement and force (CSV time_s,displacement_mm,force_kN, DAQ export or run.sqlite).")
@click.option("--run", "run_dir", default=None, type=click.Path(exists=True, file_okay=False),
              help="Error budget of a hybrid run: what makes it differ from the numerical simulation.")
@click.option("--displacement-channel", default="CHANNEL0", show_default=True, help="--specimen DAQ: channel of the displacement.")
@click.option("--displacement-scale", default=10.0, show_default=True, type=float, help="--specimen DAQ: mm per volt of the displacement.")
@click.option("--format", "fmt", type=click.Choice(["csv", "daq", "run"]), default=None,
              help="Record format (default: from the file name and its first bytes).")
@click.option("--command-channel", default="CHANNEL2", show_default=True, help="DAQ: channel of the command.")
@click.option("--measured-channel", default="CHANNEL0", show_default=True, help="DAQ: channel of the measured displacement.")
@click.option("--force-channel", default="CHANNEL1", show_default=True, help="DAQ: channel of the force ('none': no force).")
@click.option("--command-scale", default=10.0, show_default=True, type=float, help="DAQ: mm per volt of the command.")
@click.option("--measured-scale", default=10.0, show_default=True, type=float, help="DAQ: mm per volt of the measured displacement.")
@click.option("--force-scale", default=9.80665, show_default=True, type=float, help="DAQ: kN per volt of the force.")
@click.option("--actuator", default=None, help="Run recordings: which actuator (default: the first).")
@click.option("--controller-rate", "controller_rate", default=None, type=float, metavar="HZ",
              help="The servo loop's rate, when the record is sampled slower (a DAQ beside the controller): the model "
                   "steps at it and is compared at the record's samples.")
@click.option("--train-fraction", default=0.6, show_default=True, type=float, help="Fit on this first part.")
@click.option("--choose-fraction", default=0.2, show_default=True, type=float,
              help="Choose between models on this next part; the rest scores the choice.")
@click.option("--margin", default=None, type=float, help="Held-out improvement a cause must reach to be named (default 1.1).")
@click.option("--json", "as_json", is_flag=True, help="Print the diagnosis as JSON on stdout.")
@click.option("--report", "report_dir", default=None, type=click.Path(file_okay=False),
              help="Write plots, report.md, diagnosis.json and actuator_model.toml in this folder.")
@click.option("--model", "model_path", default=None, type=click.Path(dir_okay=False),
              help="Write the extended model (TOML) here (default with --report: DIR/actuator_model.toml).")
def diagnose(file, specimen_file, run_dir, displacement_channel, displacement_scale, fmt, command_channel, measured_channel,
             force_channel, command_scale, measured_scale, force_scale, actuator, controller_rate, train_fraction, choose_fraction,
             margin, as_json, report_dir, model_path) -> None:
    """Name what the actuator model gets wrong in a measured record FILE and extend it; with
    --specimen, what a linear spring and dashpot miss in a specimen's force; with --run, the
    error budget of a hybrid run."""
    given = [x for x in (file, specimen_file, run_dir) if x]
    if len(given) != 1:
        click.echo("hsio diagnose: error: give one of FILE (an actuator record), --specimen FILE or --run RUN_DIR", err=True)
        sys.exit(2)
    scales = {"--displacement-scale": displacement_scale, "--command-scale": command_scale,
              "--measured-scale": measured_scale, "--force-scale": force_scale}
    for option, value in scales.items():
        if value == 0:  # negative: a transducer wired the other way round
            _fail(f"{option} = 0 would read every sample of that channel as 0: give the transducer's mm (kN) per volt")
    if margin is not None and not MARGIN_BOUNDS[0] <= margin <= MARGIN_BOUNDS[1]:
        _fail(f"--margin = {margin:g} is out of bounds: a cause is named when it divides the held-out error by at "
              f"least this factor, within {MARGIN_BOUNDS[0]:g}..{MARGIN_BOUNDS[1]:g} (below 1 a model that does worse "
              f"would be named)")
    _refuse_unused(file, specimen_file, run_dir, fmt)
    if specimen_file:
        _specimen(specimen_file, fmt, displacement_channel, force_channel, displacement_scale, force_scale, actuator,
                  train_fraction, choose_fraction, margin, as_json, report_dir, model_path)
        return
    if run_dir:
        _budget(run_dir, as_json, report_dir)
        return
    from hsio.diagnose import report as report_mod
    from hsio.diagnose.modelfile import write_model
    from hsio.diagnose.readers import DaqChannels, read_record
    from hsio.diagnose.selection import MARGIN
    from hsio.diagnose.selection import diagnose as run_diagnosis

    force = "" if force_channel.lower() in ("", "none") else force_channel
    channels = DaqChannels(command_channel, measured_channel, force, command_scale, measured_scale, force_scale)
    record = _reading(lambda: read_record(file, fmt, channels, actuator), file)
    d = _reading(lambda: run_diagnosis(record, train_fraction=train_fraction, choose_fraction=choose_fraction,
                                       margin=MARGIN if margin is None else margin,
                                       controller_rate_hz=controller_rate), file)

    def write() -> dict:
        out = report_mod.write_report(d, report_dir) if report_dir else {}
        if model_path:
            out["model"] = str(write_model(model_path, report_mod.model_params(d), report_mod.provenance(d)))
        return out

    files = _writing(write)
    result = d.to_json()
    if files:
        result["files"] = files
    if as_json:
        click.echo(json.dumps(result, indent=2))
        return
    b, e = d.baseline, d.extended
    loop = d.record.controller_dt
    click.echo(f"record      {record.source}: {record.n} samples at {record.rate_hz:g} Hz"
               + (f" (controller at {1.0 / loop:g} Hz)" if loop is not None and loop < record.dt else "") + f", fit on {d.n_train}, "
               f"choose on {d.n_choose - d.n_train}, score on {record.n - d.n_choose}")
    click.echo(f"baseline    lag {1e3 * b.params['lag_s']:.2f} ms: RMS {b.rms_train_mm:.4f} mm fitted, {b.rms_test_mm:.4f} mm scored")
    for c in d.candidates:
        click.echo(f"candidate   {c.cause:<20} scored {c.fit.rms_test_mm:.4f} mm  gain {c.gain:6.3f}  "
                   f"(choosing {c.choose_gain:6.3f}){'  *' if c.named else ''}")
    why = d.too_short or d.slow_record
    click.echo(f"cause       {d.cause}" + (f" ({why})" if why else ""))
    if d.timing is not None:
        click.echo(f"timing      {d.timing.verdict}: {d.timing.reason}")
    if d.gain_tie is not None:
        click.echo(f"gain tie    {d.gain_tie.verdict}: {d.gain_tie.reason}")
    click.echo(f"residual    {d.residual_json()['remains']}")
    click.echo(f"extended    {e.name}: scored {e.rms_test_mm:.4f} mm, gain {d.gain:.2f}")
    click.echo(f"            {', '.join(f'{k} = {v:.5g}' for k, v in e.params.items())}")
    for name, path in files.items():
        click.echo(f"{name:<11} {path}")


# The options each form reads (docs/diagnose.md); the channel options only of a DAQ export.
_DAQ_OPTIONS = {"actuator": ("command_channel", "measured_channel", "force_channel", "command_scale", "measured_scale",
                             "force_scale"),
                "specimen": ("displacement_channel", "force_channel", "displacement_scale", "force_scale")}
_FIT_OPTIONS = ("fmt", "actuator", "train_fraction", "choose_fraction", "margin", "model_path")


def _refuse_unused(file, specimen_file, run_dir, fmt) -> None:
    """An option given on the command line that the chosen form or record format does not read
    is refused, naming it (a scale typed for a CSV file would otherwise be ignored unseen)."""
    from click.core import ParameterSource

    ctx = click.get_current_context()
    given = {p.name: p.opts[0] for p in ctx.command.params
             if p.name and ctx.get_parameter_source(p.name) not in (None, ParameterSource.DEFAULT)}
    if run_dir:
        used, what, hint = ("run_dir", "as_json", "report_dir"), "--run (an error budget)", "it reads only --json and --report"
    else:
        form = "specimen" if specimen_file else "actuator"
        path = specimen_file or file
        if fmt is None:
            from hsio.diagnose.readers import detect_format

            fmt = _reading(lambda: detect_format(path), path)
        daq = _DAQ_OPTIONS[form] if fmt == "daq" else ()
        own = ("controller_rate",) if form == "actuator" else ()
        used = ("file", "specimen_file", "as_json", "report_dir", *_FIT_OPTIONS, *own, *daq)
        what = f"{'--specimen' if specimen_file else 'an actuator record'} in {fmt} format"
        flags = {p.name: p.opts[0] for p in ctx.command.params}
        hint = (f"its DAQ options are {', '.join(flags[n] for n in daq)}" if daq
                else "the channel and scale options are for a DAQ export")
    unused = [flag for name, flag in given.items() if name not in used]
    if unused:
        _fail(f"{', '.join(unused)}: not read for {what} ({hint})")


def _fail(message: str) -> NoReturn:
    click.echo(f"hsio diagnose: error: {message}", err=True)
    sys.exit(2)


def _reading(action: Callable[[], T], source) -> T:
    """Read and analyse the input: a file that cannot be read is named as such (exit 2)."""
    try:
        return action()
    except OSError as exc:
        where = exc.filename if exc.filename is not None else source
        _fail(f"{os.fsdecode(where)}: cannot read: {exc.strerror or exc}")
    except HsioError as exc:
        _fail(str(exc))


def _writing(action: Callable[[], T]) -> T:
    """Write the report and the model: a folder or file that cannot be written is named (exit 2)."""
    try:
        return action()
    except OSError as exc:
        _fail(output_error(exc, "the report"))
    except HsioError as exc:
        _fail(str(exc))


def _specimen(path, fmt, displacement_channel, force_channel, displacement_scale, force_scale, actuator, train_fraction,
              choose_fraction, margin, as_json, report_dir, model_path) -> None:
    from hsio.diagnose.specimen_fit import MARGIN, diagnose_specimen
    from hsio.diagnose.specimen_record import read_specimen
    from hsio.diagnose.specimen_report import specimen_json, write_specimen_model, write_specimen_report

    if not 0.1 <= train_fraction <= 0.8 or not 0.05 <= choose_fraction <= 0.95 - train_fraction:
        _fail(f"fractions: train in [0.1, 0.8] and choose in [0.05, 0.95 - train], got {train_fraction}, {choose_fraction}")
    records = _reading(lambda: read_specimen(path, fmt, displacement_channel, force_channel, displacement_scale,
                                             force_scale, actuator), path)
    diagnoses = _reading(lambda: [diagnose_specimen(r, train_fraction, choose_fraction,
                                                    MARGIN if margin is None else margin) for r in records], path)

    def write() -> dict:
        out = write_specimen_report(diagnoses, report_dir) if report_dir else {}
        if model_path:
            out["model"] = str(write_specimen_model(model_path, diagnoses[-1]))
        return out

    files = _writing(write)
    result = specimen_json(diagnoses)
    if files:
        result["files"] = files
    if as_json:
        click.echo(json.dumps(result, indent=2))
        return
    for d in diagnoses:
        b, e = d.baseline, d.extended
        click.echo(f"record      {d.record.source}: {d.record.n} samples at {d.record.rate_hz:g} Hz")
        click.echo(f"baseline    k {b.params['k']:.4g} kN/mm, c {b.params['c']:.4g} kN s/mm: RMS {b.rms_test_kN:.4f} kN scored "
                   f"(sensor floor {d.floor.sensor_floor_mm:.4f} kN)")
        for c in d.candidates:
            click.echo(f"candidate   {c.cause:<16} scored {c.fit.rms_test_kN:.4f} kN  gain {c.gain:6.3f}  "
                       f"(choosing {c.choose_gain:6.3f}){'  *' if c.named else ''}")
        click.echo(f"cause       {d.cause}" + (f" ({d.too_short})" if d.too_short else ""))
        click.echo(f"extended    {e.name}: scored {e.rms_test_kN:.4f} kN, gain {d.gain:.2f}")
    for name, p in files.items():
        click.echo(f"{name:<11} {p}")


def _budget(run_dir, as_json, report_dir) -> None:
    from hsio.diagnose.budget import error_budget, write_budget

    b = _reading(lambda: error_budget(run_dir), run_dir)
    files = _writing(lambda: write_budget(b, report_dir) if report_dir else {})
    result = {**b.to_json(), **({"files": files} if files else {})}
    if as_json:
        click.echo(json.dumps(result, indent=2))
        return
    click.echo(b.table())
