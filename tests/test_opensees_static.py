"""Static preloads under `hsio serve opensees` (docs/opensees.md, "Static preloads"): ramped in
before the model's first trial, held through the session, ramped off only after DIE, refused
beyond the actuator's capacity; and a preload already on is ramped from where it stands."""

from __future__ import annotations

import json
import sqlite3
import time

import numpy as np
import pytest

from hsio.opensees import protocol as p
from test_opensees_support import RawClient, one_step_session, serving, session_over, wait_for, write_config

PRELOAD_KN = 125.0  # preloaded_column's axial load
K_LATERAL = 0.75  # kN/mm, its lateral element


def static_table(path):
    db = sqlite3.connect(path)
    try:
        rows = np.array(db.execute("SELECT phase, target_axial, force_axial FROM static ORDER BY step").fetchall())
        summary = {k: json.loads(v) for k, v in db.execute("SELECT key, value FROM summary")}
    finally:
        db.close()
    return rows, summary


def serve_column(tmp_path, extra: str = ""):
    return serving(write_config(tmp_path, "preloaded_column", ["lateral"], extra=extra), log=None)


def test_preload_is_held_through_the_session_and_ramped_off_after_die(tmp_path):
    """Default (noisy) emulator: the lateral force is the lateral spring's alone, the axial load
    is on before the first trial and stays within the load cell's noise, and goes off after DIE."""
    with serve_column(tmp_path) as server:
        client = RawClient(server.ports[0], timeout_s=30.0)
        try:
            client.setup()
            d = np.array([0.5, 1.0, 1.5, 1.0, 0.0, -1.0])
            forces = np.array([client.step(x, 0.01 * (k + 1)) for k, x in enumerate(d)])
            client.send(p.DIE)
        finally:
            client.close()
        assert wait_for(lambda: session_over(server), 30.0)
        lines = list(server.lines)
    # closed form: F = k d, untouched by the 125 kN axial load (noise 0.002 kN, 0.025 mm transducer)
    assert np.max(np.abs(forces - K_LATERAL * d)) < 0.05
    rows, summary = static_table(tmp_path / "records" / "run.sqlite")
    phase, target, force = rows.T
    assert list(np.unique(phase)) == [0.0, 1.0, 2.0]
    assert np.all(np.diff(phase) >= 0)  # ramp in, then the session, then ramp off
    ramp_in = phase == 0
    assert target[ramp_in][-1] == PRELOAD_KN and np.all(np.diff(target[ramp_in]) > 0)
    held = phase == 1
    assert held.sum() == len(d)  # one row per trial
    assert np.max(np.abs(force[held] - PRELOAD_KN)) < 0.05
    assert target[phase == 2][-1] == 0.0 and abs(force[-1]) < 0.05
    assert 0 < summary["static_hold_error"]["axial"] < 0.05 / PRELOAD_KN
    assert any("static preloads ramped in and held (axial 125 kN)" in line for line in lines)
    assert any("static preloads ramped off" in line for line in lines)


@pytest.mark.parametrize("ending", ["client closes without DIE", "server stops"])
def test_a_session_that_ends_without_die_leaves_the_preload_held(tmp_path, ending):
    """The model crashed (its connection closed without DIE), or the server was stopped under it:
    the preload is not ramped off."""
    with serve_column(tmp_path) as server:
        client = RawClient(server.ports[0], timeout_s=30.0)
        try:
            client.setup()
            client.step(1.0, 0.01)
        finally:
            if ending == "server stops":
                server.close()
            client.close()
        if ending != "server stops":
            assert wait_for(lambda: session_over(server), 30.0)
        lines = list(server.lines)
    rows, summary = static_table(tmp_path / "records" / "run.sqlite")
    assert 2.0 not in rows[:, 0]  # never ramped off
    assert abs(rows[-1, 2] - PRELOAD_KN) < 0.05
    assert "axial" in summary["static_hold_error"]
    assert any("static preloads held, not ramped off" in line for line in lines), lines
    assert not any("ramped off" in line and "not ramped off" not in line for line in lines)


SLOW_RAMP = """[structure]
name = "slow_ramp_column"
dt = 0.01
[[dof]]
name = "top"
mass = 0.01
[[experimental]]
name = "lateral"
dof = "top"
model = { kind = "linear", k = 0.75 }
[[static]]
name = "axial"
force_kN = 125.0
ramp_s = RAMP
model = { kind = "linear", k = 50.0 }
"""


def serve_slow_ramp(tmp_path, ramp_s: float):
    """preloaded_column's rig with ``ramp_s`` of ramp, on the real-time clock: a ramp takes that
    long on the wall too, so a test can act in the middle of it."""
    (tmp_path / "column.toml").write_text(SLOW_RAMP.replace("RAMP", repr(ramp_s)))
    config = tmp_path / "serve.toml"
    config.write_text(f'[structure]\nfile = "column.toml"\n[hardware]\nclock = "realtime"\n[output]\nplots = false\n'
                      f'[opensees]\nelements = ["lateral"]\nout = "{tmp_path / "records"}"\n')
    return serving(config, log=None)


def test_a_client_that_reconnects_while_the_preload_ramps_off_opens_the_next_session(tmp_path):
    """The model ends with DIE and is started again at once: the new client waits for the ramp
    off (it is not refused), and its session ramps the preload in again from where it stands."""
    ramp_s = 1.0
    with serve_slow_ramp(tmp_path, ramp_s) as server:
        first = RawClient(server.ports[0], timeout_s=30.0)
        try:
            first.setup()
            first.step(0.5, 0.01)
            first.send(p.DIE)
        finally:
            first.close()
        again = RawClient(server.ports[0], timeout_s=30.0)
        try:
            again.setup()
            force = again.step(1.0, 0.01)
            again.send(p.DIE)
        finally:
            again.close()
        assert wait_for(lambda: session_over(server), 30.0)
        lines = list(server.lines)
    assert not any("already has a client" in line for line in lines), lines
    assert abs(force - K_LATERAL * 1.0) < 0.05
    rows, _ = static_table(tmp_path / "records" / "run.sqlite")
    assert rows[-1, 0] == 2.0 and rows[-1, 1] == 0.0 and abs(rows[-1, 2]) < 0.05  # ramped off to the end
    rows2, _ = static_table(tmp_path / "records" / "run-2.sqlite")
    ramp_in = rows2[rows2[:, 0] == 0]
    assert ramp_in[0, 1] < 0.25 * PRELOAD_KN  # from the ~0 kN the first session left, not from 125 kN
    assert ramp_in[-1, 1] == PRELOAD_KN


@pytest.mark.parametrize("ramp", ["ramp in", "ramp off"])
def test_stopping_the_server_stops_a_ramp_and_the_preload_holds_where_it_stands(tmp_path, ramp):
    """Ctrl-C (the server closing) in the middle of a ramp does not wait for its end: the ramp
    stops, the axial actuator is left in force control at the force it had reached, and the log
    and the record say so."""
    ramp_s = 4.0
    with serve_slow_ramp(tmp_path, ramp_s) as server:
        client = RawClient(server.ports[0], timeout_s=30.0)
        try:
            client.setup()  # the ramp in runs before the first answer
            if ramp == "ramp off":
                client.step(0.5, 0.01)
                client.send(p.DIE)
            sign = "ramping the static preloads off" if ramp == "ramp off" else "actuators of lateral open"
            assert wait_for(lambda: any(sign in line for line in server.lines), 10.0)
            time.sleep(0.2 * ramp_s)
            server.close()
        finally:
            client.close()
        lines = list(server.lines)
    stopped = [line for line in lines if f"the {ramp} of the static preloads was stopped" in line]
    assert stopped and "force control left at axial" in stopped[0] and "measured" in stopped[0], lines
    rows, summary = static_table(tmp_path / "records" / "run.sqlite")
    phase = 0.0 if ramp == "ramp in" else 2.0
    assert rows[-1, 0] == phase and 0.0 < rows[-1, 1] < PRELOAD_KN  # stopped before the end of the ramp
    assert abs(rows[-1, 2] - rows[-1, 1]) < 0.5  # the measured force is at the last target
    assert f"{ramp} of the static preloads was stopped" in summary["stopped"]
    assert not any("static preloads ramped off" in line for line in lines)


def test_a_ramp_stops_at_the_step_its_stop_is_asked_and_ends_exactly_at_its_end():
    """ActuatorSite's ramp on the lockstep emulator: a stop that answers true at step k + 1
    leaves the target k steps of the way and says so; a ramp that runs out ends exactly on its
    end value (not a rounding away from it)."""
    from hsio import api
    from hsio.sites.actuators import RampStopped
    from hsio.structures import get_structure

    structure = get_structure("preloaded_column")
    quiet = {"noise_mm": 0.0, "resolution_mm": 0.0, "force_noise_kN": 0.0, "force_resolution_kN": 0.0}
    with api.open_site(structure, "emulator://", options=quiet) as site:
        steps = int(np.ceil(structure.static[0].ramp_s / site.loop.t_d))
        asked, k = [], steps // 2
        assert k >= 2
        with pytest.raises(RampStopped, match=rf"ramp in of the static preloads was stopped after {k} of {steps} steps; "
                                              rf"force control left at axial {PRELOAD_KN * k / steps:.4g} kN \(measured"):
            site.preload(stop=lambda: asked.append(1) or len(asked) > k)
        assert site.static_targets[0] == pytest.approx(PRELOAD_KN * k / steps)
        site.preload()
        assert site.static_targets[0] == PRELOAD_KN
        site.release()
        assert site.static_targets[0] == 0.0


def test_a_preload_beyond_the_capacity_is_refused_before_anything_moves(tmp_path):
    with serve_column(tmp_path, extra="[emulator]\nforce_limit_kN = 100.0\n") as server:
        client = RawClient(server.ports[0], timeout_s=30.0)
        try:
            client.setup()
            assert client.answered_as_stopped(pending=False, timeout_s=10.0)  # no session: NaN, closed on DIE
        finally:
            client.close()
        assert wait_for(lambda: session_over(server), 30.0)
        lines = list(server.lines)
    refusal = [line for line in lines if "cannot open the actuators" in line]
    assert refusal and "static preload 'axial'" in refusal[0] and "125" in refusal[0], lines
    db = sqlite3.connect(tmp_path / "records" / "run.sqlite")
    try:
        assert db.execute("SELECT count(*) FROM steps").fetchone()[0] == 0
        tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
    finally:
        db.close()
    assert "static" not in tables  # nothing was ramped


def test_a_preload_already_on_is_ramped_from_where_it_stands():
    """A second preload() on a loaded static actuator (a session after one that left it held)
    does not drop the load to zero and ramp it back: every target of its ramp is the preload."""
    from hsio import api
    from hsio.structures import get_structure

    structure = get_structure("preloaded_column")
    quiet = {"noise_mm": 0.0, "resolution_mm": 0.0, "force_noise_kN": 0.0, "force_resolution_kN": 0.0}
    with api.open_site(structure, "emulator://", options=quiet) as site:
        site.preload()
        first = len(site.static_log)
        site.preload()
        again = [t[0] for phase, _, t, f, _ in site.static_log[first:]]
        forces = [f[0] for phase, _, t, f, _ in site.static_log[first:]]
    assert again and min(again) > PRELOAD_KN - 0.5  # from zero, the first target would be 12.5 kN
    assert min(forces) > PRELOAD_KN - 0.5


def test_a_preload_left_short_by_the_ramp_in_is_logged_and_recorded(tmp_path, monkeypatch):
    """A preload still outside the ramp-in's tolerance after its hold (here a tolerance nothing
    meets, the emulated load cell settling on its target exactly): the session runs under it, and
    the log and the record's events say so."""
    from hsio.recording import Run
    from hsio.sites.actuators import ActuatorSite

    monkeypatch.setattr(ActuatorSite, "PRELOAD_REACHED", -1.0)
    with serve_column(tmp_path) as server:
        one_step_session(server)
        lines = list(server.lines)
    assert any("warning: static preload 'axial' reads" in line and "the session runs under it" in line for line in lines), lines
    events = Run(tmp_path / "records" / "run.sqlite").events()
    assert [e["kind"] for e in events if e["actuator"] == "axial"] == ["warning"]


if __name__ == "__main__":  # pragma: no cover
    pytest.main([__file__, "-q"])
