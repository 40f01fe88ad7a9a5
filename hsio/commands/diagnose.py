"""`hsio diagnose`: replay the actuator model against a measured record, name what it gets wrong,
extend it and measure the gain on held-out data (docs/diagnose.md)."""

from __future__ import annotations

import json
import sys

import click

from hsio.errors import HsioError


@click.command()
@click.argument("file", type=click.Path(exists=True, dir_okay=False))
@click.option("--format", "fmt", type=click.Choice(["csv", "daq", "run"]), default=None,
              help="Record format (default: from the file name and its first bytes).")
@click.option("--command-channel", default="CHANNEL2", show_default=True, help="DAQ: channel of the command.")
@click.option("--measured-channel", default="CHANNEL0", show_default=True, help="DAQ: channel of the measured displacement.")
@click.option("--force-channel", default="CHANNEL1", show_default=True, help="DAQ: channel of the force ('none': no force).")
@click.option("--command-scale", default=10.0, show_default=True, type=float, help="DAQ: mm per volt of the command.")
@click.option("--measured-scale", default=10.0, show_default=True, type=float, help="DAQ: mm per volt of the measured displacement.")
@click.option("--force-scale", default=9.80665, show_default=True, type=float, help="DAQ: kN per volt of the force.")
@click.option("--actuator", default=None, help="Run recordings: which actuator (default: the first).")
@click.option("--train-fraction", default=0.7, show_default=True, type=float, help="Fit on this first part, judge on the rest.")
@click.option("--margin", default=None, type=float, help="Held-out improvement a cause must reach to be named (default 1.1).")
@click.option("--json", "as_json", is_flag=True, help="Print the diagnosis as JSON on stdout.")
@click.option("--report", "report_dir", default=None, type=click.Path(file_okay=False),
              help="Write plots, report.md, diagnosis.json and actuator_model.toml in this folder.")
@click.option("--model", "model_path", default=None, type=click.Path(dir_okay=False),
              help="Write the extended model (TOML) here (default with --report: DIR/actuator_model.toml).")
def diagnose(file, fmt, command_channel, measured_channel, force_channel, command_scale, measured_scale, force_scale,
             actuator, train_fraction, margin, as_json, report_dir, model_path) -> None:
    """Name what the actuator model gets wrong in a measured record FILE and extend it."""
    from hsio.diagnose import report as report_mod
    from hsio.diagnose.modelfile import write_model
    from hsio.diagnose.readers import DaqChannels, read_record
    from hsio.diagnose.selection import MARGIN
    from hsio.diagnose.selection import diagnose as run_diagnosis

    force = "" if force_channel.lower() in ("", "none") else force_channel
    channels = DaqChannels(command_channel, measured_channel, force, command_scale, measured_scale, force_scale)
    try:
        record = read_record(file, fmt, channels, actuator)
        d = run_diagnosis(record, train_fraction=train_fraction, margin=MARGIN if margin is None else margin)
        files = report_mod.write_report(d, report_dir) if report_dir else {}
        if model_path:
            files["model"] = str(write_model(model_path, report_mod.model_params(d), report_mod.provenance(d)))
    except HsioError as exc:
        click.echo(f"hsio diagnose: error: {exc}", err=True)
        sys.exit(2)
    result = d.to_json()
    if files:
        result["files"] = files
    if as_json:
        click.echo(json.dumps(result, indent=2))
        return
    b, e = d.baseline, d.extended
    click.echo(f"record      {record.source}: {record.n} samples at {record.rate_hz:g} Hz, fit on {d.n_train}, judged on {record.n - d.n_train}")
    click.echo(f"baseline    lag {1e3 * b.params['lag_s']:.2f} ms: RMS {b.rms_train_mm:.4f} mm fitted, {b.rms_test_mm:.4f} mm held out")
    for c in d.candidates:
        click.echo(f"candidate   {c.cause:<20} held out {c.fit.rms_test_mm:.4f} mm  gain {c.gain:6.3f}{'  *' if c.named else ''}")
    click.echo(f"cause       {d.cause}")
    click.echo(f"extended    {e.name}: held out {e.rms_test_mm:.4f} mm, gain {d.gain:.2f}")
    click.echo(f"            {', '.join(f'{k} = {v:.5g}' for k, v in e.params.items())}")
    for name, path in files.items():
        click.echo(f"{name:<11} {path}")
