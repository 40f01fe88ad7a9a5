"""What a served session's record says besides its steps (docs/opensees.md): the safety layer's
warnings and trips with their step, the hold and the stop, steps that OpenSees committed after
going back from a failed attempt (``retried``), and steps whose time does not advance
(``time_back``)."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from hsio.opensees import protocol as p
from hsio.recording import Run
from test_opensees_support import (QUIET, RawClient, need_openseespy, serving, session_over, step_together, wait_for,
                                  write_config)


def finish(server, c: RawClient) -> Run:
    c.send(p.DIE)
    c.close()
    assert wait_for(lambda: session_over(server))
    return Run(sorted((server.tmp / "records").glob("run*.sqlite"))[-1])


def serve(tmp_path, extra: str = ""):
    config = write_config(tmp_path, "validation", ["C1"], extra="timeout_s = 5.0\n" + QUIET + extra)
    srv = serving(config)
    server = srv.__enter__()
    server.tmp = tmp_path
    return srv, server


def test_a_warning_of_the_safety_layer_is_recorded_with_its_step(tmp_path):
    """C1's stroke is +/-127 mm: the warning band starts at 90 %, 114.3 mm, crossed on the way
    to 116 mm (step 58 of 2 mm steps)."""
    srv, server = serve(tmp_path)
    try:
        c = RawClient(server.ports[0])
        c.setup()
        for k in range(1, 60):
            c.step(2.0 * k, 0.01 * k)
        run = finish(server, c)
    finally:
        srv.__exit__(None, None, None)
    warnings = [e for e in run.events() if e["kind"] == "warning"]
    assert [(e["step"], e["actuator"]) for e in warnings] == [(58, "C1")]
    assert "beyond 90% of the limit" in warnings[0]["message"]
    flags = dict(zip(run.steps["step"].tolist(), run.steps["flags"].tolist()))
    assert flags[58] == "warning" and {f for s, f in flags.items() if s != 58} == {""}
    assert not [e for e in run.events() if e["kind"] in ("hold", "stop")]  # ended with DIE, hold confirmed
    assert any("step 58: warning: C1" in line for line in server.lines)


def test_a_trip_is_recorded_with_the_hold_and_the_stop(tmp_path):
    """The emulated actuator lags its command by more than 0.05 mm for more than 0.01 s on a
    2 mm step: the following-error interlock trips in the middle of step 3's motion."""
    srv, server = serve(tmp_path, "[safety]\nfollowing_error_mm = 0.05\nfollowing_time_s = 0.01\n")
    try:
        c = RawClient(server.ports[0])
        c.setup()
        c.step(0.001, 0.01)
        c.step(0.002, 0.02)
        c.send(p.SET_TRIAL, [2.0], t=0.03)
        c.send(p.GET_FORCE)
        assert c.answered_as_stopped()
        c.close()
        assert wait_for(lambda: session_over(server))
    finally:
        srv.__exit__(None, None, None)
    run = Run(tmp_path / "records" / "run.sqlite")
    kinds = [(e["kind"], e["step"]) for e in run.events()]
    assert kinds == [("trip", 3), ("hold", 3), ("stop", 3)], kinds
    events = {e["kind"]: e for e in run.events()}
    assert "interlock (following)" in events["trip"]["message"] and events["trip"]["actuator"] == "C1"
    assert events["hold"]["message"] == "the actuators hold (confirmed by read-back)"
    assert "interlock (following)" in events["stop"]["message"]
    assert run.summary["steps"] == 2 and run.summary["uncommitted_trials"] == 1  # it moved part of the way
    assert run.summary["final_hold"] == "the actuators hold (confirmed by read-back)"


def test_a_step_tried_again_is_flagged_and_a_time_that_goes_back_is_recorded_as_sent(tmp_path):
    """As OpenSees does after a step that did not converge: the committed trial is sent again
    (same displacement and time), then the step is tried anew with a shorter dt. Later the
    model's clock is set back (loadConst -time 0)."""
    srv, server = serve(tmp_path)
    try:
        c = RawClient(server.ports[0])
        c.setup()
        c.step(1.0, 0.01)
        c.send(p.SET_TRIAL, [2.0], t=0.02)  # the failed attempt: two iterates move the actuator
        c.ask(p.GET_FORCE)
        c.send(p.SET_TRIAL, [2.5], t=0.02)
        c.ask(p.GET_FORCE)
        c.send(p.SET_TRIAL, [1.0], t=0.01)  # revertToLastCommit: the committed trial again
        c.step(1.5, 0.015)  # the step tried again, committed
        c.step(1.75, 0.02)
        c.step(0.5, 0.01)  # the clock set back
        run = finish(server, c)
    finally:
        srv.__exit__(None, None, None)
    assert run.steps["time_s"].tolist() == [0.01, 0.015, 0.02, 0.01]
    assert run.actuator("target", "C1").tolist() == [1.0, 1.5, 1.75, 0.5]
    assert run.steps["flags"].tolist() == ["", "retried", "", "time_back"]
    events = {e["kind"]: e for e in run.events()}
    assert events["retried"]["step"] == 2 and "2 trial motion(s)" in events["retried"]["message"]
    assert events["time_back"]["step"] == 4 and "0.01 s is not after the previous step's 0.02 s" in \
        events["time_back"]["message"]
    assert run.summary["retried_steps"] == 1 and run.summary["abandoned_trials"] == 2
    assert run.summary["uncommitted_trials"] == 0


def test_a_trial_repeated_within_a_step_is_not_a_retry(tmp_path):
    """OpenSees' AlphaOS sends each step's trial twice: no step is flagged."""
    srv, server = serve(tmp_path)
    try:
        c = RawClient(server.ports[0])
        c.setup()
        for k in range(1, 4):
            c.send(p.SET_TRIAL, [0.5 * k], t=0.01 * k)
            c.ask(p.GET_FORCE)
            c.send(p.SET_TRIAL, [0.5 * k], v=[3.0], t=0.01 * k)
            c.send(p.COMMIT)
        run = finish(server, c)
    finally:
        srv.__exit__(None, None, None)
    assert run.steps["flags"].tolist() == ["", "", ""] and run.events() == []
    assert run.summary["retried_steps"] == 0


FAILING_ANALYSIS = textwrap.dedent("""
    import json, sys
    import openseespy.opensees as ops
    port, dt = int(sys.argv[1]), 0.01
    ops.wipe(); ops.model("basic", "-ndm", 1, "-ndf", 1)
    ops.node(1, 0.0); ops.node(2, 0.0); ops.fix(1, 1); ops.mass(2, 0.0017)
    ops.element("genericClient", 1, "-node", 2, "-dof", 1, "-server", port, "127.0.0.1")
    ops.setNodeVel(2, 1, 50.0, "-commit")
    ops.constraints("Plain"); ops.numberer("Plain"); ops.system("FullGeneral")
    ops.algorithm("Newton"); ops.integrator("Newmark", 0.5, 0.25); ops.analysis("Transient")
    out = {"t": [], "u": [], "failed": []}
    for i in range(8):
        if i in (2, 5):  # a tolerance no iterate meets: the step fails, then is made in two halves
            ops.test("NormDispIncr", 1e-30, 2)
            if ops.analyze(1, dt) == 0:
                sys.exit("the step did not fail")
            out["failed"].append(len(out["t"]) + 1)
            steps = (dt / 2, dt / 2)
        else:
            steps = (dt,)
        ops.test("NormDispIncr", 1e-6, 10)
        for h in steps:
            if ops.analyze(1, h) != 0:
                sys.exit("analysis failed")
            out["t"].append(ops.getTime()); out["u"].append(ops.nodeDisp(2, 1))
    ops.wipe()
    print(json.dumps(out))
""")


def test_opensees_analysis_that_fails_and_retries_keeps_its_committed_steps_and_flags_the_retries(tmp_path):
    """A Newmark-Newton analysis whose steps 3 and 6 fail to converge and are made again in two
    halves: OpenSees sends its committed trial again (it cannot revert the element) and tries
    anew. The record holds exactly the committed steps, at OpenSees' times and displacements, and
    flags the first step after each failure."""
    need_openseespy()
    srv, server = serve(tmp_path)
    try:
        proc = subprocess.run([sys.executable, "-c", FAILING_ANALYSIS, str(server.ports[0])], capture_output=True,
                              text=True, timeout=120)
        assert proc.returncode == 0, proc.stdout + proc.stderr
        assert wait_for(lambda: session_over(server))
    finally:
        srv.__exit__(None, None, None)
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["failed"] == [3, 7]
    run = Run(tmp_path / "records" / "run.sqlite")
    np.testing.assert_allclose(run.steps["time_s"], out["t"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(run.dof("u", "C1"), out["u"], rtol=1e-12, atol=1e-12)
    flagged = [s for s, f in zip(run.steps["step"].tolist(), run.steps["flags"].tolist()) if f]
    assert flagged == [3, 7] and set(run.steps["flags"].tolist()) == {"", "retried"}
    assert run.summary["retried_steps"] == 2 and run.summary["abandoned_trials"] >= 4


def test_an_element_that_left_is_recorded_as_its_actuator_stands(tmp_path):
    """C2's client vanishes (no DIE) after step 2 while C1's goes on: C2's actuator keeps 2 mm,
    and the rows of steps 3 and 4 say so (target, measured); C2 has no model values there (NULL).
    Its leaving is an event; the session, ended by C1's DIE, did not stop."""
    config = write_config(tmp_path, "validation", ["C1", "C2"], extra="timeout_s = 5.0\n" + QUIET)
    with serving(config) as server:
        a, b = RawClient(server.ports[0]), RawClient(server.ports[1])
        a.setup()
        b.setup()
        step_together((a, b), [1.0, 2.0])
        b.close()
        assert wait_for(lambda: server.lab._call(lambda: server.lab.active == {0}))
        for k in (3, 4):
            a.step(1.0 * k, 0.01 * k)
        a.send(p.DIE)
        a.close()
        assert wait_for(lambda: session_over(server))
    run = Run(tmp_path / "records" / "run.sqlite")
    assert run.steps["time_s"].tolist() == [0.01, 0.02, 0.03, 0.04]
    assert run.actuator("target", "C2").tolist() == [1.0, 2.0, 2.0, 2.0]
    np.testing.assert_allclose(run.actuator("disp", "C2"), [1.0, 2.0, 2.0, 2.0], atol=0.01)  # quiet sensors
    np.testing.assert_allclose(run.actuator("force", "C2"), 0.536 * np.array([1.0, 2.0, 2.0, 2.0]), rtol=0.01)
    u2 = run.dof("u", "C2")
    assert u2[:2].tolist() == [1.0, 2.0] and np.isnan(u2[2:]).all() and np.isnan(run.dof("r", "C2")[2:]).all()
    assert run.actuator("target", "C1").tolist() == [1.0, 2.0, 3.0, 4.0]
    assert [(e["kind"], e["step"], e["actuator"]) for e in run.events()] == [("left", 3, "C2")]
    assert "closed the connection" in run.events()[0]["message"] and run.summary["stopped"] == ""


def test_a_force_asked_after_the_commit_moves_nothing(tmp_path):
    """OpenSees asks a genericClient for its force after commitState when the script reads it
    (eleForce, an element recorder): the committed step's force is answered, the actuators do
    not move again, and no motion is left uncommitted at the end."""
    srv, server = serve(tmp_path)
    try:
        c = RawClient(server.ports[0])
        c.setup()
        for k in (1, 2, 3):
            force = c.step(0.5 * k, 0.01 * k)
            assert c.ask(p.GET_FORCE)[0] == pytest.approx(force, rel=1e-9)
            assert server.lab.trials == k  # one motion per step
        run = finish(server, c)
    finally:
        srv.__exit__(None, None, None)
    assert run.summary["uncommitted_trials"] == 0 and run.summary["steps"] == 3
    assert not any("never committed" in line for line in server.lines)


def test_stopping_the_server_after_a_session_ended_does_not_report_that_session_again(tmp_path):
    """A session that ended with a trial never committed says so once; the server stopped later
    (no session open) reports nothing more about it."""
    srv, server = serve(tmp_path)
    try:
        c = RawClient(server.ports[0])
        c.setup()
        c.step(1.0, 0.01)
        c.send(p.SET_TRIAL, [2.0], t=0.02)
        c.ask(p.GET_FORCE)
        c.close()  # gone without DIE, its last motion uncommitted
        assert wait_for(lambda: session_over(server))
    finally:
        srv.__exit__(None, None, None)
    assert sum("never committed" in line for line in server.lines) == 1
    assert sum("ended (" in line for line in server.lines) == 1


def test_a_records_folder_that_cannot_be_written_is_named_and_the_server_goes_on(tmp_path):
    """The records folder became a file while the server ran: the client is closed with a line
    naming the folder (not the actuators), and the server serves again once it is a folder."""
    srv, server = serve(tmp_path)
    try:
        (tmp_path / "records").write_text("not a folder")  # no session has made it yet
        c = RawClient(server.ports[0])
        c.setup()
        assert c.answered_as_stopped(pending=False)  # no session: NaN to every request, closed on DIE
        c.close()
        refusal = [line for line in server.lines if "record" in line and "element C1" in line]
        assert refusal and str(tmp_path / "records") in refusal[0] and "actuators" not in refusal[0], server.lines
        assert server.lab.hold_message.startswith("the hold could not be read back: the record of session")
        (tmp_path / "records").unlink()
        (tmp_path / "records").mkdir()
        c = RawClient(server.ports[0])
        c.setup()
        c.step(1.0, 0.01)
        run = finish(server, c)
    finally:
        srv.__exit__(None, None, None)
    assert run.summary["steps"] == 1


def test_a_session_stopped_by_the_server_is_recorded_as_stopped_not_as_a_client_that_left(tmp_path):
    """The server is stopped (Ctrl-C) while its element waits for the model's next message: the
    record says the server stopped the session, not that the element closed its connection."""
    srv, server = serve(tmp_path)
    try:
        c = RawClient(server.ports[0])
        c.setup()
        c.step(1.0, 0.01)
        assert wait_for(lambda: server.lab.steps == 1)
    finally:
        srv.__exit__(None, None, None)
    c.close()
    run = Run(tmp_path / "records" / "run.sqlite")
    assert "server" in run.summary["stopped"] and "server" in run.summary["end"]
    stop = [e for e in run.events() if e["kind"] == "stop"]
    assert len(stop) == 1 and "server" in stop[0]["message"] and "closed" not in stop[0]["message"]


def test_elements_of_a_session_the_server_stopped_are_not_recorded_as_leaving_it(tmp_path):
    """Two elements when the server is stopped: one stop, and no 'left' event saying that the
    other elements go on."""
    config = write_config(tmp_path, "validation", ["C1", "C2"], extra="timeout_s = 5.0\n" + QUIET)
    with serving(config) as server:
        a, b = RawClient(server.ports[0]), RawClient(server.ports[1])
        a.setup()
        b.setup()
        for c in (a, b):
            c.send(p.SET_TRIAL, [0.5], t=0.01)
            c.ask(p.GET_FORCE)
        for c in (a, b):
            c.send(p.COMMIT)
        assert wait_for(lambda: server.lab.steps == 1)
    a.close()
    b.close()
    run = Run(tmp_path / "records" / "run.sqlite")
    assert [e["kind"] for e in run.events()] == ["hold", "stop"] and "server" in run.summary["stopped"]


def test_a_failed_element_ends_the_session_at_once_for_the_others(tmp_path):
    """C1's trial is refused (beyond the stroke) in the middle of a step, as an OpenSees model
    asks its elements one after the other. The session ends at once (C2 is detached, the record
    closed with the stop), not after C2 has been silent for timeout_s; C1 is answered NaN, and so
    is C2 when the model asks it next: both connections stay open until DIE."""
    config = write_config(tmp_path, "validation", ["C1", "C2"], extra="timeout_s = 30.0\n" + QUIET)
    with serving(config) as server:
        a, b = RawClient(server.ports[0]), RawClient(server.ports[1])
        try:
            a.setup()
            b.setup()
            step_together((a, b), [0.5])
            a.send(p.SET_TRIAL, [500.0], t=0.02)
            a.send(p.GET_FORCE)
            assert wait_for(lambda: session_over(server), timeout_s=5.0)  # C2 sent nothing: not after 30 s
            assert a.answered_as_stopped()
            assert b.answered_as_stopped(pending=False)
        finally:
            a.close()
            b.close()
    run = Run(tmp_path / "records" / "run.sqlite")
    assert run.summary["steps"] == 1 and "beyond the stroke" in run.summary["stopped"]
    assert "closed the connection" not in run.summary["end"] and "C1" in run.summary["end"]
    assert [e["kind"] for e in run.events()] == ["hold", "stop"]


def test_a_failed_element_ends_only_its_own_session_for_the_others(tmp_path):
    """C2 said DIE, and the model built again connected C2 at once: that client waits for the
    next session. C1 then fails, its session closes and C2's new client opens the next one;
    however late the server detaches the failed session's other elements, the next session's
    client is none of them: it goes on, its forces measured, not answered NaN."""
    config = write_config(tmp_path, "validation", ["C1", "C2"], extra="timeout_s = 30.0\n" + QUIET)
    with serving(config) as server:
        end_others = server._end_session_of_others

        def late(*args):  # the failed session's others are detached once the next session is open
            assert wait_for(lambda: server.lab._call(lambda: server.lab.sessions == 2 and server.lab.active == {1}))
            end_others(*args)

        server._end_session_of_others = late
        a, b = RawClient(server.ports[0]), RawClient(server.ports[1])
        again = None
        try:
            a.setup()
            b.setup()
            step_together((a, b), [0.5])
            b.send(p.DIE)
            assert b.closed_by_server()
            again = RawClient(server.ports[1])
            again.setup()
            assert wait_for(lambda: any("joins the next session" in line for line in server.lines))
            a.send(p.SET_TRIAL, [500.0], t=0.02)
            a.send(p.GET_FORCE)
            assert a.answered_as_stopped()
            force = again.step(0.5, 0.01)
            assert np.isfinite(force) and force > 0, server.lines
            again.send(p.DIE)
            assert again.closed_by_server()
        finally:
            a.close()
            b.close()
            if again is not None:
                again.close()
    assert Run(tmp_path / "records" / "run-2.sqlite").summary["steps"] == 1


def test_a_model_stepping_other_than_the_structures_dt_is_told_the_lab_time_scale(tmp_path):
    """Each step's motion lasts TR dt of lab time (the structure's dt, 0.01 s), whatever the
    model's time step: a model stepping 0.005 s runs the lab at 2 TR, not TR. Once its steady
    time step shows (5 steps alike), the session says so once: an event naming both steps and
    the lab's time scale, the step flagged ``time_step``. A model stepping dt is not told."""
    srv, server = serve(tmp_path)
    try:
        c = RawClient(server.ports[0])
        c.setup()
        for k in range(1, 9):
            c.step(0.1 * k, 0.01 * k)  # the structure's dt: nothing said
        for k in range(1, 9):
            c.step(0.8 + 0.1 * k, 0.08 + 0.005 * k)
        run = finish(server, c)
    finally:
        srv.__exit__(None, None, None)
    flags = run.steps["flags"].tolist()
    assert flags == [""] * 12 + ["time_step"] + [""] * 3  # steps 9 .. 13 alike: said at step 13, once
    (event,) = [e for e in run.events() if e["kind"] == "time_step"]
    assert event["step"] == 13
    assert "time step 0.005 s is not the structure's dt 0.01 s" in event["message"]
    assert "runs 40 times slower than the model's, not TR = 20 times" in event["message"]
    assert any("warning: step 13: the model's time step 0.005 s" in line for line in server.lines)
