"""OpenSees (openseespy, in a subprocess) drives hsio's emulated actuators through genericClient
elements: the same response as `hsio run` of the same structure (docs/opensees.md)."""

from __future__ import annotations

import numpy as np
import pytest

from hsio import config as config_mod
from hsio import runner
from hsio.recording import Run
from hsio.result import max_error_pct
from test_opensees_support import QUIET, cli_server, need_openseespy, run_model, serving, write_config

DURATION_S = 2.0
SHORT_S = 1.0  # the tests of a variant compare the first second with the shared reference


def hsio_run(tmp_path, structure: str, duration_s: float, extra: str = "") -> Run:
    path = tmp_path / f"run_{structure}.toml"
    path.write_text(f'[structure]\nname = "{structure}"\n[record]\nduration_s = {duration_s}\n'
                    f"[output]\nplots = false\nns = false\n" + extra)
    runner.run(config_mod.load(path), tmp_path / f"hsio_{structure}")
    return Run(tmp_path / f"hsio_{structure}" / "run.sqlite")


@pytest.fixture(scope="module")
def validation_reference(tmp_path_factory) -> Run:
    """`hsio run` of the validation structure over DURATION_S, shared by the tests of this module."""
    return hsio_run(tmp_path_factory.mktemp("reference"), "validation", DURATION_S)


def u_of(run: Run, names, steps: int | None = None) -> np.ndarray:
    return np.column_stack([run.dof("u", n) for n in names])[:steps]


def test_validation_structure_matches_hsio_run_within_1_percent(tmp_path, validation_reference):
    need_openseespy()
    config = write_config(tmp_path, "validation", ["C1", "C2"])
    with serving(config) as server:
        u, out = run_model("validation", server.ports, tmp_path / "u.npy", DURATION_S)
    reference = validation_reference
    steps = len(reference.steps["step"])
    assert u.shape == (steps + 1, 2)
    worst, per_dof = max_error_pct(u[1:], u_of(reference, ["C1", "C2"]))
    assert worst < 1.0, per_dof
    record = Run(tmp_path / "records" / "run.sqlite")  # the server's record: one row per committed step
    assert len(record.steps["step"]) == steps
    assert record.summary["steps"] == steps and "DIE" in record.summary["end"]
    # OpenSees' AlphaOS drives the element to the displacement at t + alpha dt, between two
    # predictions, where hsio's alpha-OS drives it to the prediction (docs/opensees.md).
    targets = np.column_stack([record.actuator("target", n) for n in ("C1", "C2")])
    predicted = np.column_stack([reference.actuator("target", n) for n in ("C1", "C2")])
    between = 0.95 * predicted + 0.05 * np.vstack([np.zeros((1, 2)), predicted[:-1]])
    assert max_error_pct(targets, between)[0] < 1.0


def test_a_model_in_newtons_and_metres_is_converted_at_the_server(tmp_path, validation_reference):
    need_openseespy()
    config = write_config(tmp_path, "validation", ["C1", "C2"], extra="length_factor = 1000.0\nforce_factor = 0.001\n")
    with serving(config) as server:
        u, _ = run_model("validation", server.ports, tmp_path / "u.npy", SHORT_S, units="N-m")
    reference = validation_reference
    steps = len(u) - 1
    worst, per_dof = max_error_pct(u[1:], u_of(reference, ["C1", "C2"], steps))
    assert worst < 1.0, per_dof
    record = Run(tmp_path / "records" / "run.sqlite")  # recorded in hsio's units
    forces = record.actuator("force", "C1")[:, None], reference.actuator("force", "C1")[:steps, None]
    assert max_error_pct(*forces)[0] < 5.0  # kN, not N (a factor 1000); the first second's small forces are noisy


def test_two_labs_each_serving_one_element_of_one_model(tmp_path, validation_reference):
    need_openseespy()
    lab1 = write_config(tmp_path, "validation", ["C1"], name="lab1.toml")
    lab2 = write_config(tmp_path, "validation", ["C2"], name="lab2.toml")
    with cli_server(lab1, tmp_path / "lab1") as (_, p1), cli_server(lab2, tmp_path / "lab2") as (_, p2):
        u, _ = run_model("validation", [p1["C1"], p2["C2"]], tmp_path / "u.npy", SHORT_S)
    reference = validation_reference
    steps = len(u) - 1
    worst, per_dof = max_error_pct(u[1:], u_of(reference, ["C1", "C2"], steps))
    assert worst < 1.0, per_dof
    for lab, name in (("lab1", "C1"), ("lab2", "C2")):
        record = Run(tmp_path / lab / "run.sqlite")
        assert record.actuator_names == [name] and len(record.steps["step"]) == steps


def test_structure_II_one_element_per_actuator(tmp_path):
    # Its peaks are below 1 mm: the emulator's 0.025 mm quantiser alone would make two HS runs
    # differ by about 1 %, so the sensors are quiet here.
    need_openseespy()
    config = write_config(tmp_path, "structure_II", ["BF", "IF"], extra=QUIET)
    with serving(config) as server:
        u, _ = run_model("structure_II", server.ports, tmp_path / "u.npy", SHORT_S)
    reference = hsio_run(tmp_path, "structure_II", SHORT_S, extra=QUIET)
    worst, per_dof = max_error_pct(u[1:], u_of(reference, ["BF", "IF", "BF_mirror"]))
    assert worst < 1.0, per_dof


def test_opensees_killed_mid_run_leaves_a_clean_record(tmp_path):
    import subprocess
    import sys

    from test_opensees_support import EXAMPLE, session_over, wait_for

    need_openseespy()
    config = write_config(tmp_path, "validation", ["C1", "C2"])
    with serving(config) as server:
        proc = subprocess.Popen([sys.executable, str(EXAMPLE), "validation", "--ports", *map(str, server.ports),
                                 "--duration", "20"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            assert wait_for(lambda: server.lab.steps >= 20, timeout_s=120)
        finally:
            proc.kill()
            proc.wait(timeout=30)
        assert wait_for(lambda: session_over(server), timeout_s=30)  # the actuators hold, the record is closed
    record = Run(tmp_path / "records" / "run.sqlite")
    steps = record.steps["step"]
    assert len(steps) >= 20 and steps.tolist() == list(range(1, len(steps) + 1))
    assert record.summary["steps"] == len(steps)
    assert "closed" in record.summary["end"] or "connection lost" in record.summary["end"]
