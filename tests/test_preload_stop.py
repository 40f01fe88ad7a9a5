"""A stop (key, socket, signal) during a ramp of the static preloads ends the ramp where it stands
and the run as the operator's (exit status 5); a preload's ramp is bounded."""

import numpy as np
import pytest

import hsio
from hsio.errors import ConfigError
from hsio.safety.control import RunControl
from hsio.safety.status import OPERATOR, OperatorStop, exit_status
from hsio.structure_file import parse_structure
from hsio.structures import StaticLoad


class StopAfter(RunControl):
    """A control whose stop is asked at its ``n``-th look (a signal arriving mid-ramp)."""

    def __init__(self, n: int):
        super().__init__()
        self.looks, self.n = 0, n

    @property
    def stop_requested(self) -> bool:
        self.looks += 1
        if self.looks == self.n:
            self.request_stop("stopped by SIGTERM during HS")
        return self.state == "stopping"


def run(control):
    structure = hsio.load_structure("preloaded_column")  # 125 kN over 2 s of lab time: 20 ramp steps at TR 10
    ground = hsio.synthetic_record(duration_s=0.5, dt=structure.dt, pga_g=0.3, seed=2)
    site = hsio.open_site(structure, "emulator://", test_rate=10)
    return site, lambda: hsio.simulate(structure, ground, site, control=control)


def test_a_stop_during_the_ramp_in_ends_it_where_it_stands():
    site, simulate = run(StopAfter(6))
    with site:
        with pytest.raises(OperatorStop, match=r"stopped by SIGTERM during HS: the ramp in of the static preloads was "
                                               r"stopped after 5 of 20 steps") as info:
            simulate()
        assert exit_status(info.value) == OPERATOR
        phases = [p for p, *_ in site.static_log]
        assert phases == ["ramp_in"] * 5  # no step of the record, no ramp off
        force = site.loop.feedback()[1].force_kN
        assert force == pytest.approx(125.0 * 5 / 20, rel=0.05)  # held where the ramp stood


def test_a_stop_during_the_ramp_off_keeps_the_whole_record():
    site, simulate = run(None)
    with site:
        steps = len(simulate().t) - 1  # the same run, to count its steps
    control = StopAfter(20 + 3)  # the 20 looks of the ramp in, then 2 steps of the ramp off
    site, simulate = run(control)
    with site:
        with pytest.raises(hsio.ExperimentStopped, match="ramp off of the static preloads") as info:
            simulate()
    partial = info.value.result
    assert exit_status(info.value) == OPERATOR
    assert partial.steps == steps and "ramp off" in partial.stopped
    phases = [p for p, *_ in partial.static_log]
    assert phases.count("ramp_off") == 2 and phases.count("test") == steps
    assert np.isfinite(partial.static_hold_error[0])


def test_a_ramp_longer_than_an_hour_is_refused():
    base = ('[structure]\ndt = 0.01\n[[dof]]\nname = "x"\nmass = 0.01\n[[experimental]]\ndof = "x"\n'
            'model = { kind = "linear", k = 1.0 }\n[[static]]\nname = "axial"\nforce_kN = 100.0\n'
            'model = { kind = "linear", k = 50.0 }\n')
    with pytest.raises(ConfigError, match=r"c\.toml: static\[0\]\.ramp_s: 1e\+09 s is out of bounds"):
        parse_structure(base + "ramp_s = 1e9\n", "c.toml")
    assert parse_structure(base + "ramp_s = 3600\n", "c.toml").static[0].ramp_s == 3600.0
    with pytest.raises(ConfigError, match=r"static load 'axial': ramp_s: 7200 s is out of bounds"):
        StaticLoad("axial", 100.0, {"kind": "linear", "k": 50.0}, 7200.0)


def test_a_record_refused_is_refused_before_the_preload_moves_anything():
    structure = hsio.load_structure("preloaded_column")
    too_long = hsio.GroundMotion("long", 0.01, np.zeros(1_200_000))  # 1.2e6 steps at 0.01 s: beyond the bound
    with hsio.open_site(structure, "emulator://", test_rate=10) as site:
        with pytest.raises(hsio.HsioError, match="more than the bound"):
            hsio.simulate(structure, too_long, site)
        assert site.static_log == [] and abs(site.loop.feedback()[1].force_kN) < 0.1


class PauseAt(RunControl):
    """A control whose pause is asked at its ``n``-th look, then ``then`` ("resume" or "stop")
    asked from another thread a moment later (the operator at the page)."""

    def __init__(self, n: int, then: str):
        super().__init__()
        self.looks, self.n, self.then = 0, n, then

    @property
    def stop_requested(self) -> bool:
        import threading

        self.looks += 1
        if self.looks == self.n:
            self.phase_seen = self.phase  # what the control socket (the monitor's page) says then
            self.request_pause("socket")
            later = self.request_resume if self.then == "resume" else lambda: self.request_stop("stopped by the operator")
            threading.Timer(0.3, later).start()
        return self.state == "stopping"


@pytest.mark.parametrize("then", ["resume", "stop"])
def test_a_pause_during_the_ramp_in_holds_it_there(then):
    """A pause asked during a ramp holds after the ramp's step under way, not after the ramp."""
    control = PauseAt(6, then)
    site, simulate = run(control)
    with site:
        paused_at = []
        pause = site.pause
        site.pause = lambda: paused_at.append(len(site.static_log)) or pause()
        if then == "stop":
            with pytest.raises(OperatorStop, match=r"the ramp in of the static preloads was stopped after 6 of 20"):
                simulate()
        else:
            result = simulate()
            assert [p for p, *_ in result.static_log].count("ramp_in") == 20
            assert result.static_log[-1][3][0] == pytest.approx(0.0, abs=1.0)  # ramped off again
        assert paused_at == [6]
        assert control.phase_seen == "ramp-in"


class PauseAfterStep(RunControl):
    """Pauses after step ``n`` of the record and resumes 0.2 s later (the operator at the page)."""

    def __init__(self, n: int):
        super().__init__()
        self.n = n

    def checkpoint(self, site, step, log=None):
        import threading

        if step == self.n:
            self.request_pause("socket")
            threading.Timer(0.2, self.request_resume).start()
        return super().checkpoint(site, step, log)


def test_a_preload_held_through_a_pause_goes_on_in_force_control_after_it():
    """The hold of a pause is in displacement control; on resuming, the static actuator goes back
    to force control before its next command (125 kN), which is never sent as 125 mm."""
    structure = hsio.load_structure("preloaded_column")
    ground = hsio.synthetic_record(duration_s=0.5, dt=structure.dt, pga_g=0.3, seed=2)
    with hsio.open_site(structure, "emulator://", test_rate=10) as site:
        result = hsio.simulate(structure, ground, site, control=PauseAfterStep(10))
        assert result.steps == 50
        assert result.static_hold_error[0] < 0.01  # held within 1 % of 125 kN, across the pause too


def test_a_run_in_force_control_paused_and_resumed_equals_the_unpaused_run():
    """The element's actuator goes back to force control after the pause's hold: the paused run
    is the unpaused one (the emulator is deterministic), not one whose force commands went out
    as displacements for a moment."""
    import warnings

    from hsio.secant import SecantEstimator

    structure = hsio.load_structure("structure_I")
    ground = hsio.synthetic_record(duration_s=0.6, dt=structure.dt, pga_g=0.2, seed=3)
    runs = []
    for control in (None, PauseAfterStep(40)):
        with warnings.catch_warnings(), hsio.open_site(structure, "emulator://", test_rate=10,
                                                       estimator=SecantEstimator("average", 16, 0.1)) as site:
            warnings.simplefilter("ignore")
            runs.append(hsio.simulate(structure, ground, site, method="force_control", control=control))
    assert runs[1].force_control[1:].all()
    np.testing.assert_allclose(runs[1].u, runs[0].u, atol=1e-9)


def test_a_pause_asked_before_the_first_step_holds_before_it():
    """The operator pressed Pause during the start-up (the page is up before the dry run): the
    run holds before its first step, not after it, and goes on as if it had not paused."""
    import threading

    structure = hsio.load_structure("validation")
    ground = hsio.synthetic_record(duration_s=0.2, dt=structure.dt, pga_g=0.2, seed=3)
    with hsio.open_site(structure, "emulator://", test_rate=10) as site:
        reference = hsio.simulate(structure, ground, site)
    control = RunControl()
    control.request_pause("socket")
    threading.Timer(0.2, control.request_resume).start()
    with hsio.open_site(structure, "emulator://", test_rate=10) as site:
        steps_at_pause = []
        pause = site.pause
        site.pause = lambda: steps_at_pause.append(site.loop.clock.now_s) or pause()
        result = hsio.simulate(structure, ground, site, control=control)
    assert steps_at_pause == [0.0]  # not a controller period had run: no step taken
    np.testing.assert_allclose(result.u, reference.u, atol=1e-9)


def _run_with_a_lagging_axial(tmp_path):
    """`hsio run` of preloaded_column whose axial actuator does not follow its force ramp: it trips
    (following) before the first step, exit 4."""
    from click.testing import CliRunner

    from hsio.cli import main

    cfg = tmp_path / "run.toml"
    cfg.write_text('[structure]\nname = "preloaded_column"\n[record]\nduration_s = 1.0\n[test]\nrate = 10.0\n'
                   '[emulator]\nforce_lag_s = 5.0\n[output]\nplots = false\n'
                   '[safety]\nkeys = false\nfollowing_error_kN = 2.0\nfollowing_time_s = 0.05\n')
    result = CliRunner().invoke(main, ["run", str(cfg), "--out", str(tmp_path / "o")])
    assert result.exit_code == 4, result.output
    assert "interlock (following) on actuator 'axial'" in result.output
    return result


def test_an_interlock_in_the_ramp_in_is_recorded_and_told_with_the_hold(tmp_path):
    """An axial actuator that does not follow its force ramp trips before the first step: the
    record has the trip, the hold and the stop, and `hsio run` says the actuators hold."""
    from hsio.recording import Run

    result = _run_with_a_lagging_axial(tmp_path)
    assert "the actuators hold (confirmed by read-back)" in result.output
    run = Run(tmp_path / "o" / "run.sqlite")
    events = run.events()
    assert [e["kind"] for e in events][-3:] == ["trip", "hold", "stop"]
    assert events[-3]["actuator"] == "axial" and run.summary["steps"] == 0


def _tables_not_written(monkeypatch):
    from hsio.errors import RecordError
    from hsio.recording import Recorder

    def full(self, tables):
        raise RecordError(f"{self.path}: the preload tables could not be written (database or disk is full)")

    monkeypatch.setattr(Recorder, "write_tables", full)


def test_a_stop_in_the_ramp_in_whose_tables_cannot_be_written_says_so(tmp_path, monkeypatch):
    """The operator's stop stays what is raised, and it says that the ramp's tables are not in the record."""
    from hsio.recording import Recorder

    _tables_not_written(monkeypatch)
    structure = hsio.load_structure("preloaded_column")
    ground = hsio.synthetic_record(duration_s=0.5, dt=structure.dt, pga_g=0.3, seed=2)
    recorder = Recorder(tmp_path / "run.sqlite", structure.dof_names, structure.experimental_names)
    with hsio.open_site(structure, "emulator://", test_rate=10) as site:
        with pytest.raises(OperatorStop, match="the ramp in of the static preloads was stopped") as info:
            hsio.simulate(structure, ground, site, control=StopAfter(6), recorder=recorder)
    recorder.close()
    assert any("the preload ramp's tables could not be written to the record" in note and "disk is full" in note
               for note in getattr(info.value, "__notes__", []))


def test_hsio_run_tells_a_trip_in_the_ramp_in_whose_tables_cannot_be_written(tmp_path, monkeypatch):
    """The trip is what `hsio run` reports (exit 4), and its message says the ramp's tables are not in the record."""
    _tables_not_written(monkeypatch)
    result = _run_with_a_lagging_axial(tmp_path)
    assert "the preload ramp's tables could not be written to the record" in result.output
