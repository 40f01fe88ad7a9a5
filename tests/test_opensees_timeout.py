"""The silence timeout of the genericClient server counts only silence that work in progress
does not explain (docs/opensees.md): with a real-time clock an element that waits while the
actuators execute another element's motion is not dropped, a client silent otherwise is."""

from __future__ import annotations

import pytest

from hsio.opensees import protocol as p
from hsio.recording import Run
from test_opensees_support import QUIET, RawClient, serving, session_over, wait_for, write_config

# Real-time clock: one motion lasts TR dt = 60 x 0.01 s = 0.6 s, longer than the 0.3 s timeout.
SLOW = "timeout_s = 0.3\n[hardware]\nclock = \"realtime\"\n[test]\nrate = 60.0\nhold_fraction = 0.0\nn_avg = 1\n" + QUIET


def test_an_element_waiting_while_another_moves_is_not_dropped(tmp_path):
    """C1 and C2 step as one OpenSees model does: both trials, then C1's force (one motion of
    both actuators, 0.6 s) while C2's client says nothing, then C2's force and both commits."""
    config = write_config(tmp_path, "validation", ["C1", "C2"], extra=SLOW)
    with serving(config) as server:
        a, b = RawClient(server.ports[0]), RawClient(server.ports[1])
        a.setup()
        b.setup()
        for k in (1, 2):
            a.send(p.SET_TRIAL, [0.5 * k], t=0.01 * k)
            b.send(p.SET_TRIAL, [0.5 * k], t=0.01 * k)
            a.ask(p.GET_FORCE)  # a motion of 0.6 s on the real-time clock: twice the timeout
            assert b.ask(p.GET_FORCE)[0] == pytest.approx(0.536 * 0.5 * k, rel=0.05)
            a.send(p.COMMIT)
            b.send(p.COMMIT)
        a.send(p.DIE)
        b.send(p.DIE)
        a.close()
        b.close()
        assert wait_for(lambda: session_over(server))
    run = Run(tmp_path / "records" / "run.sqlite")
    assert run.summary["steps"] == 2 and run.summary["stopped"] == "" and run.events() == []


def test_an_element_that_committed_waits_out_another_elements_motion(tmp_path):
    """C1 moves and commits first; C2 then moves (0.6 s) and commits: C1's wait for the step
    is not cut short by the timeout while C2's motion runs."""
    config = write_config(tmp_path, "validation", ["C1", "C2"], extra=SLOW)
    with serving(config) as server:
        a, b = RawClient(server.ports[0]), RawClient(server.ports[1])
        a.setup()
        b.setup()
        for k in (1, 2):
            a.step(0.5 * k, 0.01 * k)
            b.step(0.5 * k, 0.01 * k)
        assert a.ask(p.GET_TIME)[0] == pytest.approx(0.02)  # C1 is still served after step 2
        a.send(p.DIE)
        b.send(p.DIE)
        a.close()
        b.close()
        assert wait_for(lambda: session_over(server))
    run = Run(tmp_path / "records" / "run.sqlite")
    assert run.summary["steps"] == 2 and run.summary["stopped"] == "" and run.events() == []


def test_silence_after_the_motion_still_drops_the_element(tmp_path):
    """Once the motion is over, a client silent for timeout_s is dropped."""
    config = write_config(tmp_path, "validation", ["C1"], extra=SLOW)
    with serving(config) as server:
        c = RawClient(server.ports[0])
        c.setup()
        c.step(0.5, 0.01)
        assert c.closed_by_server(timeout_s=5.0)
        c.close()
        assert wait_for(lambda: session_over(server))
    run = Run(tmp_path / "records" / "run.sqlite")
    assert run.summary["steps"] == 1 and "silent for 0.3 s" in run.summary["end"]
