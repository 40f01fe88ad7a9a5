"""The error budget of a hybrid run (`hsio diagnose --run`): structure I on an emulated actuator
with a 20 ms lag, the physical wall 20 % stiffer than its model. The budget must account for
most of the HS-vs-NS difference and name the specimen mismatch as its main source."""

import dataclasses
import json

import pytest
from click.testing import CliRunner

from hsio import config as cfg
from hsio.commands.diagnose import diagnose
from hsio.runner import run


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    import hsio.emulators.local as local

    real = local.make_controllers

    def stiffer(elements, table):  # the physical wall: 20 % stiffer and stronger than the model says
        return real([dataclasses.replace(e, specimen={**e.specimen, "k0": 1.2 * e.specimen["k0"], "F0": 1.2 * e.specimen["F0"]})
                     for e in elements], table)

    out = tmp_path_factory.mktemp("budget_run")
    config = cfg.from_dict({"structure": {"name": "structure_I"}, "record": {"pga_g": 0.5, "synthetic_duration_s": 4.0},
                            "test": {"rate": 10.0}, "emulator": {"lag_s": 0.02}, "output": {"plots": False}})
    local.make_controllers = stiffer
    try:
        run(config, out)
    finally:
        local.make_controllers = real
    return out


def test_budget_names_the_specimen_mismatch(run_dir, tmp_path):
    result = CliRunner().invoke(diagnose, ["--run", str(run_dir), "--json", "--report", str(tmp_path / "b")])
    assert result.exit_code == 0, result.stderr
    budget = json.loads(result.stdout)
    assert budget["accounted"] >= 0.90
    assert budget["main_source"] == "specimen"
    shares = {s["source"]: s["share"] for s in budget["sources"]}
    assert shares["specimen"] > shares["tracking"] > shares["force_noise"] - 0.01
    assert budget["specimen_models"][0]["rms_force_kN"] < budget["specimen_models"][0]["rms_force_structure_model_kN"] / 3
    assert (tmp_path / "b" / "budget.png").stat().st_size > 10_000
    assert "specimen-model mismatch" in (tmp_path / "b" / "budget.md").read_text()


def test_budget_refuses_a_folder_without_a_run(tmp_path):
    result = CliRunner().invoke(diagnose, ["--run", str(tmp_path)])
    assert result.exit_code == 2 and "no run.sqlite" in result.stderr


def test_a_run_that_cannot_be_read_is_not_reported_as_an_unwritable_report(tmp_path, monkeypatch):
    """An OSError while reading (here: the recording, by a stand-in for a failing disk) names the
    input and says it cannot be read; one while writing says the report cannot be written."""
    import errno

    import hsio.diagnose.budget as budget

    def unreadable(run_dir):
        raise OSError(errno.EIO, "Input/output error", str(tmp_path / "run.sqlite"))

    monkeypatch.setattr(budget, "error_budget", unreadable)
    result = CliRunner().invoke(diagnose, ["--run", str(tmp_path), "--report", str(tmp_path / "b")])
    assert result.exit_code == 2
    assert f"{tmp_path / 'run.sqlite'}: cannot read: Input/output error" in result.stderr
    assert "cannot write" not in result.stderr


def test_a_report_folder_that_cannot_be_written_is_named(run_dir, tmp_path):
    blocker = tmp_path / "taken"
    blocker.write_text("a file where the report folder should go")
    result = CliRunner().invoke(diagnose, ["--run", str(run_dir), "--report", str(blocker / "b")])
    assert result.exit_code == 2
    assert "cannot write the report" in result.stderr and "taken" in result.stderr
