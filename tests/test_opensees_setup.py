"""Elements beyond one DOF on one actuator (docs/opensees.md): a column top with two basic DOFs on
two actuators through its setup, an implicit (Newton) OpenSees analysis, and several elements of
one server stepping together."""

from __future__ import annotations

import math
import os
import random
import subprocess
import sys
import threading

import numpy as np
import pytest

from hsio import config as config_mod
from hsio import runner
from hsio.opensees import protocol as p
from hsio.recording import Run
from hsio.result import max_error_pct
from test_opensees_support import (QUIET, ROOT, RawClient, need_openseespy, serving, session_over, step_together,
                                  wait_for, write_config)

SETUP_EXAMPLE = ROOT / "examples" / "opensees_setup.py"
COLUMN = "column_two_actuators"
CHANNELS = ["column.top_x", "column.top_rot"]
K_COLUMN = np.array([[3.0, 3000.0], [3000.0, 4.0e6]])  # 12EI/L^3, 6EI/L^2, 4EI/L (kN, mm, rad)
FAST = "[test]\nrate = 5\n"  # the emulated rig is slow to emulate: fewer controller periods per step


def run_column(tmp_path, port: int, duration_s: float = 1.0, integrator: str = "alphaos"):
    """examples/opensees_setup.py in a subprocess: the column top's history (mm, rad) served on
    ``port``, then that of its numerical twin (OpenSees' own elasticBeamColumn)."""
    out, reference = tmp_path / "hs.npy", tmp_path / "ns.npy"
    proc = subprocess.run([sys.executable, str(SETUP_EXAMPLE), "--port", str(port), "--duration", str(duration_s),
                           "--integrator", integrator, "--pga", "0.6", "--out", str(out), "--reference", str(reference)],
                          capture_output=True, text=True, timeout=300, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return np.load(out), np.load(reference)


@pytest.fixture(scope="module")
def served_column(tmp_path_factory):
    """The column served on two emulated actuators to examples/opensees_setup.py (AlphaOS, 1 s):
    (folder of the server's record, OpenSees' history, its numerical twin's), shared."""
    need_openseespy()
    tmp = tmp_path_factory.mktemp("column")
    config = write_config(tmp, COLUMN, ["column"], extra=FAST + QUIET)
    with serving(config) as server:
        u, reference = run_column(tmp, server.ports[0])
    return tmp, u, reference


def test_column_on_two_actuators_through_its_setup_matches_opensees_own_beam(served_column):
    """The genericClient with two basic DOFs (x, rotation) on hsio's two emulated actuators, through
    the two_actuators setup, against the same model with OpenSees' elasticBeamColumn."""
    tmp, u, reference = served_column
    worst, per_dof = max_error_pct(u[1:], reference[1:])
    assert worst < 1.0, per_dof
    assert np.max(np.abs(reference[:, 1])) > 0.003  # the rotation is a real part of the response
    record = Run(tmp / "records" / "run.sqlite")
    assert record.actuator_names == CHANNELS and len(record.steps["step"]) == len(u) - 1
    targets = np.column_stack([record.actuator("target", c) for c in CHANNELS])
    answered = np.column_stack([record.dof("r", c) for c in CHANNELS])
    # the linear column: the basic forces that came back through the setup are K d, within what
    # the emulated load trains and lag leave after the force correction
    assert max_error_pct(answered, targets @ K_COLUMN.T)[0] < 5.0


def test_column_served_to_opensees_matches_hsio_run_of_the_same_structure(tmp_path, served_column):
    """`hsio run` of column_two_actuators, with the OpenSees model's damping (mass-proportional,
    2 % on mode 1), on the same emulated rig and record."""
    _, u, _ = served_column
    library = (ROOT / "hsio" / "library" / f"{COLUMN}.toml").read_text()
    assert 'kind = "rayleigh"' in library
    structure = tmp_path / "column_mass_damped.toml"
    structure.write_text(library.replace('kind = "rayleigh"', 'kind = "mass"'))
    run_toml = tmp_path / "run.toml"
    run_toml.write_text(f'[structure]\nfile = "{structure}"\n[record]\nduration_s = 1.0\n'
                        "[output]\nplots = false\nns = false\n" + FAST + QUIET)
    runner.run(config_mod.load(run_toml), tmp_path / "hsio")
    run = Run(tmp_path / "hsio" / "run.sqlite")
    hsio_u = np.column_stack([run.dof("u", d) for d in ("top_x", "top_rot")])
    worst, per_dof = max_error_pct(u[1:], hsio_u)
    assert worst < 1.0, per_dof


def test_two_dof_element_in_newtons_and_metres_with_the_exact_geometry(tmp_path):
    config = write_config(tmp_path, COLUMN, ["column"], extra="length_factor = 1000.0\nforce_factor = 0.001\n" + QUIET)
    with serving(config) as server:
        c = RawClient(server.ports[0])
        try:
            c.setup(n=2)
            K = c.ask(p.GET_INITIAL_STIFF)[:4].reshape(2, 2, order="F")
            assert K == pytest.approx(np.array([[3.0e6, 3.0e6], [3.0e6, 4.0e6]]))  # N/m, N, N m/rad
            ux_m, theta = 0.004, 0.002
            expected = K_COLUMN @ [ux_m * 1000.0, theta]  # kN, kN mm
            for k in range(3):  # to the target, then held there twice: the actuators settle
                c.send(p.SET_TRIAL, [ux_m, theta], t=0.01 * (k + 1))
                q = c.ask(p.GET_FORCE)[:2]
                assert q == pytest.approx([expected[0] * 1000.0, expected[1]], rel=0.02)  # N, N m
                c.send(p.COMMIT)
            assert c.ask(p.GET_DISP)[:2] == pytest.approx([ux_m, theta], rel=0.02)
            strokes = server.lab._call(lambda: server.lab.site.last_actuator_feedback.displacement.copy())
            c.send(p.DIE)
        finally:
            c.close()
        assert wait_for(lambda: session_over(server))
    # closed form of the rig: lower actuator at the control point, upper one 500 mm above it,
    # both 1500 mm long and horizontal at rest
    ux, L, h = ux_m * 1000.0, 1500.0, 500.0
    upper = math.hypot(L + ux - h * math.sin(theta), h * math.cos(theta) - h) - L
    assert strokes == pytest.approx([ux, upper], abs=0.05)
    assert upper - ux == pytest.approx(-h * theta, rel=0.01)
    record = Run(tmp_path / "records" / "run.sqlite")
    assert record.actuator("target", "column.top_x").tolist() == pytest.approx([ux] * 3)
    assert record.actuator("target", "column.top_rot").tolist() == pytest.approx([theta] * 3)


def test_implicit_newton_analysis_records_only_committed_steps(tmp_path):
    """Newmark with Newton iterations: the element moves to every iterate; the record holds one
    row per committed step, at the displacement OpenSees committed, and the response is that of
    OpenSees' own beam under the same integrator."""
    need_openseespy()
    config = write_config(tmp_path, COLUMN, ["column"], extra=FAST + QUIET)
    with serving(config) as server:
        u, reference = run_column(tmp_path, server.ports[0], duration_s=0.5, integrator="newmark")
        trials, steps = server.lab.trials, server.lab.steps
    worst, per_dof = max_error_pct(u[1:], reference[1:])
    assert worst < 1.0, per_dof
    assert steps == len(u) - 1 and trials > steps  # iterates that were never committed
    record = Run(tmp_path / "records" / "run.sqlite")
    assert record.steps["step"].tolist() == list(range(1, steps + 1))
    targets = np.column_stack([record.actuator("target", c) for c in CHANNELS])
    np.testing.assert_allclose(targets, u[1:], rtol=1e-9, atol=1e-12)  # the committed iterate, not a later one


def test_two_elements_of_one_server_step_together_and_each_keeps_one_client(tmp_path):
    """Two clients, one per element, each in its own thread at its own pace: every step of the
    record holds each element's own trial of that step, every force answers its own element's
    trial, and a second client for a served element is refused while the first goes on."""
    config = write_config(tmp_path, "validation", ["C1", "C2"], extra="timeout_s = 10.0\n" + QUIET)
    steps = 12
    plans = {"C1": [0.2 * (k + 1) for k in range(steps)], "C2": [-0.3 * (k + 1) for k in range(steps)]}
    stiffness = {"C1": 0.613, "C2": 0.536}
    forces: dict[str, list] = {}
    errors: list[BaseException] = []
    intruder_refused = threading.Event()
    both_connected = threading.Event()  # as in OpenSees, every element connects before the analysis

    def element(port: int, name: str, seed: int) -> None:
        pace = random.Random(seed)
        c = RawClient(port)
        try:
            c.setup()
            assert both_connected.wait(30)
            forces[name] = []
            for k, d in enumerate(plans[name]):
                forces[name].append(c.step(d, 0.01 * (k + 1)))
                threading.Event().wait(pace.uniform(0.0, 0.03))
                if name == "C2" and k == 2:  # still connected while another client asks for C2
                    intruder_refused.wait(30)
            c.send(p.DIE)
        except BaseException as exc:  # reported by the main thread
            errors.append(exc)
        finally:
            c.close()

    with serving(config) as server:
        threads = [threading.Thread(target=element, args=(port, name, seed))
                   for seed, (port, name) in enumerate(zip(server.ports, ["C1", "C2"]))]
        for t in threads:
            t.start()
        assert wait_for(lambda: len(server.lab.active) == 2)
        both_connected.set()
        assert wait_for(lambda: server.lab.steps >= 3)
        intruder = RawClient(server.ports[1])
        intruder.setup()
        assert intruder.closed_by_server()
        intruder.close()
        intruder_refused.set()
        for t in threads:
            t.join(60)
        assert not errors, errors
        assert wait_for(lambda: session_over(server))
        assert any("element C2 already has a client" in line for line in server.lines)
    for name in ("C1", "C2"):
        assert forces[name] == pytest.approx([stiffness[name] * d for d in plans[name]], abs=0.03)
    record = Run(tmp_path / "records" / "run.sqlite")
    assert record.steps["step"].tolist() == list(range(1, steps + 1))
    for name in ("C1", "C2"):
        assert record.actuator("target", name).tolist() == pytest.approx(plans[name])


def test_an_element_waiting_for_the_step_is_released_when_another_is_refused(tmp_path):
    config = write_config(tmp_path, "validation", ["C1", "C2"], extra="timeout_s = 30.0\n" + QUIET)
    with serving(config) as server:
        c1, c2 = RawClient(server.ports[0]), RawClient(server.ports[1])
        try:
            c1.setup()
            c2.setup()
            c1.step(0.5, 0.01)  # C1 committed; it waits for C2 to commit the step
            c2.send(p.SET_TRIAL, [500.0], t=0.01)  # beyond the stroke: refused, the actuators hold
            c2.send(p.GET_FORCE)
            assert c2.answered_as_stopped()
            c1.send(p.SET_TRIAL, [0.6], t=0.02)  # C1 goes on: released at once, not after timeout_s (30 s)
            c1.send(p.GET_FORCE)
            assert c1.answered_as_stopped(timeout_s=10.0)  # NaN: nothing moved for it
        finally:
            c1.close()
            c2.close()
        assert wait_for(lambda: session_over(server))
    assert any("beyond the stroke" in line for line in server.lines)
    # C1 is told why: its next request found the session stopped, or C2's stop detached it first
    assert any("session stopped earlier" in line or "element C2 stopped the session" in line for line in server.lines)
    record = Run(tmp_path / "records" / "run.sqlite")
    assert record.summary["steps"] == 0 and "beyond the stroke" in record.summary["stopped"]


def test_closing_the_server_releases_an_element_waiting_for_the_step(tmp_path):
    """C1 committed and waits (timeout_s = 30) for C2, an element of the session whose connection
    does not leave when the server shuts the sockets down (here C2 joined the lab directly, with
    no connection): closing the server wakes C1's wait itself, so C1 is told the server stops
    and its thread has ended when close() returns (a join of 0.5 s each)."""
    config = write_config(tmp_path, "validation", ["C1", "C2"], extra="timeout_s = 30.0\n" + QUIET)
    lines: list[str] = []
    with serving(config, log=lines.append) as server:
        c1 = RawClient(server.ports[0])
        try:
            c1.setup()
            assert wait_for(lambda: server.lab._call(lambda: 0 in server.lab.active))
            server.lab.attach(1)
            c1.step(0.5, 0.01)  # C1 committed; it waits for C2 to commit the step
            assert wait_for(lambda: bool(server.lab.committed_flags[0]))
            server.close(timeout_s=0.5)
            assert not [t.name for t in server._threads if t.is_alive()]
            assert not any("still running" in line for line in lines), lines
            assert c1.closed_by_server()
        finally:
            c1.close()
    assert any(line.startswith("element C1: stopped: the server is stopping") for line in lines), lines
    assert server.lab.site is None and server.lab.recorder is None and not server.lab.active


def test_three_dof_joint_on_three_actuators(tmp_path):
    """A genericClient with three basic DOFs (x, y, rotation) on the three actuators of
    joint_three_actuators: forces K d through the setup, the matrices n x n column-major."""
    K = np.array([[3.0, 0.5, 3000.0], [0.5, 6.0, 1500.0], [3000.0, 1500.0, 5.0e6]])
    config = write_config(tmp_path, "joint_three_actuators", ["joint"], extra=QUIET)
    with serving(config) as server:
        c = RawClient(server.ports[0])
        try:
            c.setup(n=3)
            assert c.ask(p.GET_INITIAL_STIFF)[:9].reshape(3, 3, order="F") == pytest.approx(K)
            assert c.ask(p.GET_TANGENT_STIFF)[:9].reshape(3, 3, order="F") == pytest.approx(K)
            d = np.array([1.5, -0.8, 0.0012])
            for k in range(2):
                c.send(p.SET_TRIAL, d.tolist(), t=0.01 * (k + 1))
                q = c.ask(p.GET_FORCE)[:3]
                c.send(p.COMMIT)
            assert q == pytest.approx(K @ d, rel=0.02)
            assert c.ask(p.GET_DISP)[:3] == pytest.approx(d, rel=0.02)
            c.send(p.DIE)
        finally:
            c.close()
        assert wait_for(lambda: session_over(server))
    record = Run(tmp_path / "records" / "run.sqlite")
    assert record.actuator_names == ["joint.joint_x", "joint.joint_y", "joint.joint_rot"]
    assert record.summary["steps"] == 2


LVDT_SPRING = """[structure]
name = "spring_on_a_compliant_load_train"
dt = 0.01
[[dof]]
name = "top"
mass = 0.01
[[experimental]]
name = "spring"
dof = "top"
model = { kind = "linear", k = 2.0 }
displacement_from = "spring_lvdt"
outer_loop = { tolerance_mm = 0.02, max_iterations = 6 }
[[instrument]]
name = "spring_lvdt"
kind = "lvdt"
element = "spring"
"""


def test_a_mass_matrix_over_a_joints_basic_dofs_is_answered_in_model_units(tmp_path):
    """[opensees] mass as a matrix over the joint's x, y, rotation (kN s^2/mm, kN s^2, kN mm s^2):
    answered to getMass as M_ij u_i u_j / (force_factor length_factor), u = length_factor for x, y
    and 1 for the rotation; damping given as a number is that number times the identity."""
    M = [[0.01, 0.0, 0.5], [0.0, 0.01, 0.0], [0.5, 0.0, 400.0]]
    lf, ff = 1000.0, 0.001  # the model in m and N
    extra = f"length_factor = {lf}\nforce_factor = {ff}\nmass = {{ joint = {M} }}\ndamping = {{ joint = 0.02 }}\n"
    config = write_config(tmp_path, "joint_three_actuators", ["joint"], extra=extra + QUIET)
    with serving(config) as server:
        c = RawClient(server.ports[0])
        try:
            c.setup(n=3)
            mass = c.ask(p.GET_MASS)[:9].reshape(3, 3, order="F")
            damp = c.ask(p.GET_DAMP)[:9].reshape(3, 3, order="F")
            c.send(p.DIE)
        finally:
            c.close()
        assert wait_for(lambda: session_over(server))
    u = np.array([lf, lf, 1.0])
    np.testing.assert_allclose(mass, np.array(M) * np.outer(u, u) / (ff * lf), rtol=1e-12)
    assert mass[0, 0] == pytest.approx(10_000.0)  # 0.01 kN s^2/mm = 10 t = 10,000 kg (N s^2/m)
    np.testing.assert_allclose(damp, 0.02 * np.eye(3) * np.outer(u, u) / (ff * lf), rtol=1e-12)


def test_an_emulated_instrument_on_an_element_not_served_is_refused_at_start(tmp_path):
    from hsio.errors import ConfigError
    from hsio.opensees.lab import Lab
    from hsio.opensees.settings import split_config
    from hsio.runner import load_run_structure

    two = LVDT_SPRING.replace('element = "spring"', 'element = "other"') + (
        '[[dof]]\nname = "side"\nmass = 0.01\n[[experimental]]\nname = "other"\ndof = "side"\n'
        'model = { kind = "linear", k = 1.0 }\n')
    (tmp_path / "two.toml").write_text(two)
    config = tmp_path / "serve.toml"
    config.write_text(f'[structure]\nfile = "two.toml"\n[opensees]\nelements = ["spring"]\nout = "{tmp_path / "r"}"\n')
    settings, run = split_config(config)
    # the structure file itself is refused: the instrument that gives the spring's displacement
    # reads another element (an outer loop would drive the spring's actuator by it)
    with pytest.raises(ConfigError, match="experimental\\[0\\]\\.displacement_from: instrument 'spring_lvdt' reads "
                                          "element 'other', not 'spring'"):
        Lab(settings, run, load_run_structure(run), log=lambda _: None)


def test_a_mass_matrix_of_the_wrong_size_is_refused_naming_the_element(tmp_path):
    from hsio.errors import ConfigError
    from hsio.opensees.lab import Lab
    from hsio.opensees.settings import split_config
    from hsio.runner import load_run_structure

    config = write_config(tmp_path, "joint_three_actuators", ["joint"], extra="mass = { joint = [[1.0, 0.0], [0.0, 1.0]] }\n")
    settings, run = split_config(config)
    with pytest.raises(ConfigError, match=r"\[opensees\] mass.joint: a 2 x 2 matrix; element 'joint' has 3 basic DOFs"):
        Lab(settings, run, load_run_structure(run), log=lambda _: None)


def test_an_element_read_by_an_external_lvdt_is_served_through_its_outer_loop(tmp_path):
    """A 2 kN/mm spring behind a load train of 0.05 mm/kN, its displacement read by an LVDT on the
    specimen (docs/setups.md). Closed form: the rod's transducer alone would leave the spring at
    d / (1 + 2 x 0.05) (5 mm -> 4.55 mm, 9.09 kN); the outer loop on the LVDT brings it to d within
    the tolerance (10 kN), and the LVDT's reading is the measured displacement answered."""
    (tmp_path / "spring.toml").write_text(LVDT_SPRING)
    config = tmp_path / "serve.toml"
    config.write_text('[structure]\nfile = "spring.toml"\n[output]\nplots = false\n'
                      f'[opensees]\nelements = ["spring"]\nout = "{tmp_path / "records"}"\n'
                      + QUIET + "compliance_mm_per_kN = 0.05\n")
    with serving(config) as server:
        c = RawClient(server.ports[0], timeout_s=30.0)
        try:
            c.setup()
            d = [2.0, 5.0, 1.0, -3.0]
            forces, measured = [], []
            for k, x in enumerate(d):
                c.send(p.SET_TRIAL, [x], t=0.01 * (k + 1))
                forces.append(float(c.ask(p.GET_FORCE)[0]))
                measured.append(float(c.ask(p.GET_DISP)[0]))
                c.send(p.COMMIT)
            c.send(p.DIE)
        finally:
            c.close()
        assert wait_for(lambda: session_over(server))
    np.testing.assert_allclose(measured, d, atol=0.02 + 1e-9)
    np.testing.assert_allclose(forces, 2.0 * np.array(d), atol=2.0 * 0.02 + 1e-6)
    record = Run(tmp_path / "records" / "run.sqlite")
    table = record.table("instruments")
    assert len(table["iterations"]) == len(d) and np.all(np.asarray(table["iterations"]) >= 1)
    np.testing.assert_allclose(table["spring_lvdt"], d, atol=0.02 + 1e-9)


def test_a_model_started_again_while_its_last_run_leaves_opens_a_session_of_its_own(tmp_path):
    """OpenSees' wipe() says DIE to one element after the other, and a model built again at once
    may connect the first element before the server has seen the others' DIE: that client starts
    the next session (its own record), never the rest of the previous one."""
    config = write_config(tmp_path, "validation", ["C1", "C2"], extra="timeout_s = 10.0\n" + QUIET)
    with serving(config) as server:
        a, b = RawClient(server.ports[0]), RawClient(server.ports[1])
        a.setup()
        b.setup()
        step_together((a, b), [0.5, 1.0])
        a.send(p.DIE)
        a.close()
        assert wait_for(lambda: server.lab._call(lambda: server.lab.active == {1}))
        again = RawClient(server.ports[0])  # the next run of the model; b has not said DIE yet
        again.setup()
        assert wait_for(lambda: 0 in server.lab.active or any("joins the next session" in line
                                                              for line in server.lines))
        b.send(p.DIE)
        b.close()
        b_again = RawClient(server.ports[1])
        b_again.setup()
        for k in (1, 2, 3):
            for c in (again, b_again):
                c.send(p.SET_TRIAL, [-0.5 * k], t=0.01 * k)
                c.ask(p.GET_FORCE)
            for c in (again, b_again):
                c.send(p.COMMIT)
        for c in (again, b_again):
            c.send(p.DIE)
            c.close()
        assert wait_for(lambda: session_over(server))
    first, second = Run(tmp_path / "records" / "run.sqlite"), Run(tmp_path / "records" / "run-2.sqlite")
    assert first.steps["time_s"].tolist() == [0.01, 0.02] and first.summary["steps"] == 2
    assert second.steps["time_s"].tolist() == [0.01, 0.02, 0.03] and set(second.steps["flags"]) == {""}
    for name in ("C1", "C2"):
        assert second.actuator("target", name).tolist() == [-0.5, -1.0, -1.5]
