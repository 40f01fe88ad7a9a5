"""The genericClient server against raw, broken and hostile clients: sizes checked, nothing
unbounded, one client per element, the actuators hold and the record stays clean
(docs/opensees.md)."""

from __future__ import annotations

import math
import os
import socket
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from hsio.opensees import protocol as p
from hsio.recording import Run
from test_opensees_support import QUIET, RawClient, serving, session_over, wait_for, write_config

HALF_STROKE_MM = 127.0
PROPERTY = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
# Each hostile data example opens and closes a session (the actuators, a record): fewer by default.
SESSIONS = settings(PROPERTY, max_examples=300 if os.environ.get("HSIO_SLOW") == "1" else 40)


@pytest.fixture
def server(tmp_path):
    """A server of C1 for one test (every example of a property test shares it)."""
    tmp = tmp_path
    config = write_config(tmp, "validation", ["C1"], extra="timeout_s = 2.0\n" + QUIET)
    with serving(config) as srv:
        srv.tmp = tmp
        yield srv


def records(server) -> list:
    """The session records in session order (run.sqlite, run-2.sqlite, ...)."""
    def session(path):
        return int(path.stem.partition("-")[2] or 1)
    return sorted((server.tmp / "records").glob("run*.sqlite"), key=session)


def good_step_works(server) -> None:
    """A well-behaved client can still connect, move the actuator, read a force and commit."""
    assert wait_for(lambda: session_over(server))
    c = RawClient(server.ports[0])
    try:
        c.setup()
        force = c.step(1.0, 0.01)
        assert 0.3 < force < 0.9  # C1: 0.613 kN/mm
        c.send(p.DIE)
    finally:
        c.close()
    assert wait_for(lambda: session_over(server))


def test_a_step_moves_the_actuator_and_is_recorded(server):
    before = len(records(server))
    c = RawClient(server.ports[0])
    c.setup()
    assert c.ask(p.GET_INITIAL_STIFF)[0] == pytest.approx(0.613)
    assert c.ask(p.GET_MASS)[:4].tolist() == [0.0] * 4 and c.ask(p.GET_DAMP)[:4].tolist() == [0.0] * 4
    forces = [c.step(d, 0.01 * (k + 1)) for k, d in enumerate((0.5, 1.0, 1.5))]
    assert forces == pytest.approx([0.613 * 0.5, 0.613, 0.613 * 1.5], abs=0.02)
    c.send(p.SET_TRIAL, [2.0], t=0.04)  # a trial that never commits
    assert c.ask(p.GET_FORCE)[0] == pytest.approx(0.613 * 2.0, abs=0.02)
    c.close()  # the element vanishes without DIE
    assert wait_for(lambda: session_over(server))
    run = Run(records(server)[before])
    assert run.steps["step"].tolist() == [1, 2, 3]  # the uncommitted trial is not a step
    assert run.actuator("target", "C1").tolist() == [0.5, 1.0, 1.5]
    assert run.summary["steps"] == 3 and "closed" in run.summary["end"]
    assert run.summary["uncommitted_trials"] == 1  # the specimen saw it; the summary says so
    assert any("1 trial motion(s) of the actuators after the last committed step (step 3) were never committed"
               in line for line in server.lines)


def test_second_client_for_the_same_element_is_refused(server):
    first = RawClient(server.ports[0])
    first.setup()
    first.step(0.2, 0.01)
    second = RawClient(server.ports[0])
    second.setup()
    assert second.closed_by_server()
    assert first.step(0.4, 0.02) == pytest.approx(0.613 * 0.4, abs=0.02)  # the first goes on
    assert any("already has a client" in line for line in server.lines)
    first.send(p.DIE)
    first.close()
    second.close()
    good_step_works(server)


def test_silent_client_is_dropped_and_its_record_closed(server):
    c = RawClient(server.ports[0])
    c.setup()
    c.step(0.3, 0.01)
    assert c.closed_by_server(timeout_s=5.0)  # timeout_s = 2 in the fixture
    c.close()
    assert wait_for(lambda: session_over(server))
    run = Run(records(server)[-1])
    assert run.summary["steps"] == 1 and "silent for 2 s" in run.summary["end"]
    good_step_works(server)


def test_huge_data_size_is_refused_without_allocating(server):
    c = RawClient(server.ports[0])
    c.sock.sendall(struct.pack("<11i", 1, 1, 1, 0, 1, 0, 0, 0, 1, 0, 2**31 - 1))
    assert c.closed_by_server()
    c.close()
    assert any("dataSize = 2147483647" in line for line in server.lines)
    good_step_works(server)


def test_trial_beyond_the_stroke_is_refused_and_the_actuator_holds(server):
    c = RawClient(server.ports[0])
    c.setup()
    c.step(0.5, 0.01)
    c.send(p.SET_TRIAL, [500.0], t=0.02)
    c.send(p.GET_FORCE)
    assert c.answered_as_stopped()  # the model is told NaN, not left reading a closed socket
    c.close()
    assert wait_for(lambda: session_over(server))
    assert any("beyond the stroke" in line for line in server.lines)
    good_step_works(server)


def test_a_trial_that_is_not_finite_stops_the_session_and_a_silent_stopped_client_is_dropped(server):
    """A diverging model sends a NaN trial: the session stops (nothing moves), the client's
    getForce is answered NaN, and the stopped client, silent, is closed after timeout_s (2 s)."""
    c = RawClient(server.ports[0])
    c.setup()
    c.step(0.5, 0.01)
    c.send(p.SET_TRIAL, [math.nan], t=0.02)
    assert np.isnan(c.ask(p.GET_FORCE)[0])
    assert wait_for(lambda: session_over(server))
    assert c.closed_by_server(timeout_s=5.0)
    c.close()
    run = Run(records(server)[-1])
    assert run.summary["steps"] == 1 and "not finite" in run.summary["stopped"]
    assert run.summary["uncommitted_trials"] == 0  # the NaN trial moved nothing
    assert any("stopped session: silent for 2 s: disconnected; 1 request(s) answered with NaN" in line
               for line in server.lines), server.lines
    good_step_works(server)


def test_closing_the_server_closes_a_stopped_client_at_once(tmp_path):
    config = write_config(tmp_path, "validation", ["C1"], extra="timeout_s = 30.0\n" + QUIET)
    lines: list[str] = []
    with serving(config, log=lines.append) as server:
        c = RawClient(server.ports[0])
        try:
            c.setup()
            c.send(p.SET_TRIAL, [500.0], t=0.01)
            assert np.isnan(c.ask(p.GET_FORCE)[0])  # stopped; the client lingers without DIE
            server.close(timeout_s=2.0)
            assert not [t.name for t in server._threads if t.is_alive()]
            assert c.closed_by_server(timeout_s=1.0)
        finally:
            c.close()
    assert any("stopped session: the server is stopping" in line for line in lines), "\n".join(lines)
    assert not any("still running" in line for line in lines), lines


def test_units_of_the_model_are_converted(tmp_path):
    config = write_config(tmp_path, "validation", ["C1"],
                          extra="length_factor = 1000.0\nforce_factor = 0.001\nmass = {C1 = 0.002}\n" + QUIET)
    with serving(config) as srv:
        c = RawClient(srv.ports[0])
        c.setup()
        assert c.ask(p.GET_TANGENT_STIFF)[0] == pytest.approx(0.613e6)  # N/m
        assert c.ask(p.GET_MASS)[0] == pytest.approx(0.002e6)  # kN s^2/mm -> N s^2/m
        force_N = c.step(0.002, 0.01)  # 2 mm
        assert force_N == pytest.approx(0.613 * 2 * 1000, rel=0.03)
        c.send(p.DIE)
        c.close()
        assert wait_for(lambda: session_over(srv))
    run = Run(tmp_path / "records" / "run.sqlite")
    assert run.actuator("target", "C1").tolist() == [2.0]


# --- property tests: whatever arrives, the server refuses cleanly and stays up ----------------

VALID = p.element_setup(1).encode()
ints = st.integers(-2**31, 2**31 - 1)
setups = st.one_of(
    st.binary(max_size=120),
    st.tuples(*[st.integers(-3, 5)] * 10, st.integers(-10, 70000)).map(lambda v: struct.pack("<11i", *v)),
    st.tuples(*[ints] * 11).map(lambda v: struct.pack("<11i", *v)),
)


def _valid_setup(raw: bytes) -> bool:
    if len(raw) < p.SETUP_BYTES:
        return False
    try:
        p.Setup.decode(raw[: p.SETUP_BYTES]).check(1, "x")
        return True
    except p.ProtocolError:
        return False


@PROPERTY
@given(raw=setups)
def test_malformed_setup_is_refused_and_the_server_stays_up(server, raw):
    assume(not _valid_setup(raw))
    refused = server.refused
    c = RawClient(server.ports[0])
    try:
        c.sock.sendall(raw)
        c.sock.shutdown(socket.SHUT_WR)
        assert c.closed_by_server()
    finally:
        c.close()
    assert wait_for(lambda: server.refused > refused)
    assert session_over(server)  # no session was opened: the actuators were never touched
    if server.refused % 10 == 0:
        good_step_works(server)  # still up and serving


actions = st.one_of(st.sampled_from([3.0, 5.0, 7.0, 10.0, 11.0, 12.0, 13.0, 14.0, 15.0]),
                    st.sampled_from([0.0, 1.0, 2.0, 4.0, 6.0, 8.0, 9.0, 98.0, -1.0, 3.5, 1e300,
                                     math.nan, math.inf]))
values = st.one_of(st.floats(-3.0, 3.0), st.floats(allow_nan=True, allow_infinity=True))
frames = st.lists(st.tuples(actions, values, st.booleans()), min_size=1, max_size=6)


@SESSIONS
@given(messages=frames)
def test_hostile_data_messages_are_refused_and_the_actuators_hold(server, messages):
    sessions = server.lab.sessions
    c = RawClient(server.ports[0], timeout_s=5.0)
    stopped = False  # a refused trial stopped the session: every later reply is NaN
    try:
        c.setup()
        for action, value, truncate in messages:
            frame = np.zeros(c.data_size)
            frame[0], frame[1] = action, value
            data = frame.astype("<f8").tobytes()
            if truncate and action == 3.0:
                c.sock.sendall(data[:100])  # half a message, then the element vanishes
                break
            c.sock.sendall(data)
            if action in (7.0, 10.0, 11.0, 12.0, 13.0, 14.0, 15.0):
                try:
                    reply = c.receive()
                except (p.PeerClosed, OSError):  # refused: the server closed the connection
                    break
                stopped = stopped or bool(np.isnan(reply[0]))
                if stopped:  # one slot (n = 1): NaN, zeros after it
                    assert np.isnan(reply[0]) and not reply[1:].any()
                else:
                    assert np.all(np.isfinite(reply))
    except OSError:
        pass
    finally:
        c.close()
    # The session (opened by the valid setup) ended: the actuators held and were released.
    assert wait_for(lambda: server.lab.sessions > sessions and session_over(server))
    for path in records(server)[-1:]:
        run = Run(path)
        targets = run.actuator("target", "C1") if len(run.steps["step"]) else np.zeros(0)
        assert np.all(np.isfinite(targets)) and np.all(np.abs(targets) <= HALF_STROKE_MM)
    if server.lab.sessions % 10 == 0:
        good_step_works(server)  # still up and serving


def test_trials_move_the_actuator_once_per_step_unless_the_displacement_changes(server):
    c = RawClient(server.ports[0])
    c.setup()
    c.step(0.5, 0.01)

    def lab_time():
        return server.lab._call(lambda: server.lab.site.lab_time_s)

    t_d = 20.0 * 0.01  # TR dt
    start = lab_time()
    c.send(p.SET_TRIAL, [1.0], t=0.02)
    c.ask(p.GET_FORCE)
    c.send(p.SET_TRIAL, [1.0], v=[3.0], t=0.02)  # AlphaOS's second trial: same displacement
    c.ask(p.GET_FORCE)
    assert lab_time() - start == pytest.approx(t_d, rel=0.05)  # one motion
    c.send(p.SET_TRIAL, [1.2], t=0.02)  # another displacement in the same step (a static search)
    assert c.ask(p.GET_FORCE)[0] == pytest.approx(0.613 * 1.2, abs=0.02)
    assert lab_time() - start == pytest.approx(2 * t_d, rel=0.05)
    c.send(p.COMMIT)
    c.send(p.DIE)
    c.close()
    assert wait_for(lambda: session_over(server))
    run = Run(records(server)[-1])
    assert run.actuator("target", "C1").tolist() == [0.5, 1.2] and run.dof("v", "C1").tolist()[-1] == 0.0


def test_secant_stiffness_is_answered_when_configured(tmp_path):
    config = write_config(tmp_path, "validation", ["C2"], extra='stiffness = "secant"\n' + QUIET)
    with serving(config) as srv:
        c = RawClient(srv.ports[0])
        c.setup()
        assert c.ask(p.GET_TANGENT_STIFF)[0] == pytest.approx(0.536)  # K^EI before any trial
        c.step(5.0, 0.01)
        c.send(p.SET_TRIAL, [14.0], t=0.02)  # beyond the 10 mm gap: 0.536, then 2.011 kN/mm
        c.ask(p.GET_FORCE)
        secant = (0.536 * 10 + 2.011 * 4 - 0.536 * 5) / 9
        assert c.ask(p.GET_TANGENT_STIFF)[0] == pytest.approx(secant, rel=0.05)
        c.send(p.DIE)
        c.close()
        assert wait_for(lambda: session_over(srv))


def test_an_element_with_more_basic_dofs_than_served_is_refused_with_the_reason(server):
    c = RawClient(server.ports[0])
    c.setup(n=2)  # e.g. '-node 1 2 -dof 1 -dof 1' for C1, a one-DOF element on one actuator
    assert c.closed_by_server()
    c.close()
    (line,) = [x for x in server.lines if "has 2 basic DOFs" in x]
    assert "served element has 1: C1" in line
    assert line.count("element C1 (127.0.0.1:") == 1, line  # the element and its peer named once
    good_step_works(server)


def test_the_server_does_not_import_the_runner():
    """The served elements' channels are named where structures live (hsio.structures), as `hsio
    run` names them (hsio.runner re-exports the same function); the server does not load the runner."""
    import subprocess
    import sys

    code = ("import sys, hsio.opensees.lab, hsio.opensees.server; "
            "assert 'hsio.runner' not in sys.modules, 'hsio.runner imported'")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    from hsio import runner, structures

    assert runner.channel_names is structures.channel_names
    assert structures.channel_names(structures.get_structure("column_two_actuators")) == ["column.top_x",
                                                                                          "column.top_rot"]


def test_a_trial_without_time_does_not_read_the_time_slot():
    """sizeCtrl time = 0: slot 3n+1 carries nothing (here 9.0, or not a number) and is not taken as
    the trial's time; with time it is."""
    n = 2
    frame = np.array([3.0, 1.0, 2.0, 0.1, 0.2, 0.01, 0.02, 9.0, 0.0])
    assert p.Trial.from_frame(frame, n, "t").t == 9.0
    untimed = p.Trial.from_frame(frame, n, "t", has_time=False)
    assert np.isnan(untimed.t) and untimed.d.tolist() == [1.0, 2.0] and untimed.a.tolist() == [0.01, 0.02]
    frame[7] = np.nan
    assert np.isnan(p.Trial.from_frame(frame, n, "t", has_time=False).t)  # a NaN there is not refused either
    with pytest.raises(p.ProtocolError, match="not finite"):
        p.Trial.from_frame(frame, n, "t")


def test_a_trial_without_velocity_or_acceleration_is_read_where_its_signals_are(server):
    """sizeCtrl vel = accel = 0 (an OpenFresco-style element sending displacements only): the
    trial is ``d, t`` from slot 1; the time is the next slot, not slot 3n+1."""
    c = RawClient(server.ports[0])
    c.sock.sendall(p.Setup((1, 0, 0, 0, 1), (0, 0, 0, 1, 0), 256).encode())
    for k in (1, 2):
        c.sock.sendall(np.pad([3.0, 0.5 * k, 0.01 * k], (0, 253)).astype("<f8").tobytes())
        assert c.ask(p.GET_TIME)[0] == 0.01 * k
        assert 0.613 * 0.5 * k == pytest.approx(c.ask(p.GET_FORCE)[0], rel=1e-9)  # quiet sensors, corrected
        c.send(p.COMMIT)
    c.send(p.DIE)
    c.close()
    assert wait_for(lambda: session_over(server))
    run = Run(records(server)[-1])
    assert run.steps["time_s"].tolist() == [0.01, 0.02]
    assert run.dof("u", "C1").tolist() == [0.5, 1.0] and run.dof("v", "C1").tolist() == [0.0, 0.0]
    frame = np.array([3.0, 1.5, 0.07, 0.0, 0.0])
    trial = p.Trial.from_frame(frame, 1, "t", has_vel=False, has_accel=False)
    assert trial.d.tolist() == [1.5] and trial.t == 0.07 and trial.v.size == trial.a.size == 0


def test_an_element_sending_trial_forces_is_refused(server):
    c = RawClient(server.ports[0])
    c.sock.sendall(p.Setup((1, 1, 1, 1, 1), (0, 0, 0, 1, 0), 256).encode())
    assert c.closed_by_server()
    c.close()
    assert any("sizeCtrl force = 1" in line and "displacements only" in line for line in server.lines)
    assert session_over(server)
