"""The `--plot` options of the command line: a format matplotlib cannot write is refused before any
work starts (exit 2, naming the option and the formats it writes), and the path printed is the file
written."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from hsio import study as fc_study
from hsio import study_mixed
from hsio.cli import main
from hsio.compensation import calibration

from test_bad_input_cli import write_calibration_csv

MIXED = ["study", "mixed", "--stiffness", "10", "--resolution", "0.01", "--force-resolution", "0.01",
         "--duration", "0.1"]
COMMANDS = {"calibrate": ["calibrate", "{d}/cal.csv"], "fc-vs-dc": ["study", "fc-vs-dc", "--thetas", "2"],
            "mixed": MIXED}
WORK = {"calibrate": (calibration, "calibrate"), "fc-vs-dc": (fc_study, "fc_vs_dc"), "mixed": (study_mixed, "grid")}


def invoke(args, tmp_path):
    write_calibration_csv(tmp_path / "cal.csv")
    return CliRunner().invoke(main, [a.format(d=tmp_path) for a in args])


@pytest.mark.parametrize("command", COMMANDS)
@pytest.mark.parametrize("name", ["x.xyz", "x.PNG.bak"])
def test_a_format_matplotlib_cannot_write_is_refused_before_the_work(tmp_path, monkeypatch, command, name):
    module, work = WORK[command]
    monkeypatch.setattr(module, work, lambda *a, **k: pytest.fail("the work started"))
    result = invoke([*COMMANDS[command], "--plot", str(tmp_path / name)], tmp_path)
    assert result.exit_code == 2, result.output
    assert "'--plot'" in result.output and f"format '{name.rpartition('.')[2]}'" in result.output
    assert ".png" in result.output and ".pdf" in result.output and ".svg" in result.output
    assert list(tmp_path.iterdir()) == [tmp_path / "cal.csv"]


def test_the_formats_named_are_those_matplotlib_writes(tmp_path):
    import matplotlib

    from hsio.commands import plot_formats

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure()
    try:
        for fmt in plot_formats():
            fig.savefig(tmp_path / f"f.{fmt}")
            assert (tmp_path / f"f.{fmt}").is_file()
    finally:
        plt.close(fig)


def fake_rows(command, monkeypatch):
    """Small rows in place of the study's, so that the real plot is drawn in a moment."""
    if command == "fc-vs-dc":
        rows = [fc_study.Row(0.0, 0.0, 0.02, theta, 1.0, 1.0) for theta in (0.2, 5.0)]
        monkeypatch.setattr(fc_study, "fc_vs_dc", lambda *a, **k: rows)


@pytest.mark.parametrize("command", COMMANDS)
@pytest.mark.parametrize("name, written", [("noext", "noext.png"), ("dot.", "dot.png"), ("fig.SVG", "fig.SVG"),
                                           ("fig.pdf", "fig.pdf")])
def test_the_path_printed_is_the_file_written(tmp_path, monkeypatch, command, name, written):
    fake_rows(command, monkeypatch)
    out = tmp_path / "out"
    out.mkdir()
    result = invoke([*COMMANDS[command], "--plot", str(out / name)], tmp_path)
    assert result.exit_code == 0, result.output
    printed = result.output.splitlines()[-1].split()[-1]
    assert printed == str(out / written)
    assert [p.name for p in out.iterdir()] == [written]
    assert Path(printed).stat().st_size > 0


@pytest.mark.parametrize("command", ["calibrate", "fc-vs-dc"])
def test_a_folder_is_not_a_plot_file(tmp_path, command):
    result = invoke([*COMMANDS[command], "--plot", f"{tmp_path}/sub/"], tmp_path)
    assert result.exit_code == 2 and "'--plot'" in result.output and "names no file" in result.output
