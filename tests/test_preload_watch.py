"""A ramp of the static preloads is watched on the measured rod every controller period: a
specimen softer than its declared K^EI moves the rod faster and farther than the check before
the ramp predicted, and the ramp stops before the rod reaches its stroke or velocity limit
(docs/setups.md, docs/safety.md section 3)."""

from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import hsio
from hsio.cli import main
from hsio.errors import ConfigError
from hsio.interfaces import Limits
from hsio.recording import Run
from hsio.safety.ramp_watch import RampWatch
from hsio.safety.settings import SafetySettings
from hsio.safety.status import INTERLOCK, InterlockTrip, exit_status
from hsio.structure_file import parse_structure
from hsio.structures import StaticLoad

LIBRARY = Path(hsio.__file__).parent / "library" / "preloaded_column.toml"
HALF_STROKE, VELOCITY = 127.0, 500.0  # the emulated actuator's (stroke 254 mm, flow limit 500 mm/s)


def soft_column(force="125.0", ramp="2.0"):
    """preloaded_column whose axial member is declared at 50 kN/mm and is 0.5 kN/mm (the
    emulator's model): 125 kN would take the rod to 250 mm, beyond its 127 mm."""
    text = (LIBRARY.read_text().replace("force_kN = 125.0", f"force_kN = {force}")
            .replace("ramp_s = 2.0", f"ramp_s = {ramp}")
            .replace('model = { kind = "linear", k = 50.0 }', 'K_EI = 50.0\nmodel = { kind = "linear", k = 0.5 }'))
    return parse_structure(text, "soft.toml")


def ramp_in(structure):
    """Open the emulator, run the structure's preload against a short record; the trip raised."""
    ground = hsio.synthetic_record(duration_s=0.3, dt=structure.dt, pga_g=0.3, seed=2)
    site = hsio.open_site(structure, "emulator://", test_rate=10)
    with site:
        with pytest.raises(InterlockTrip) as info:
            hsio.simulate(structure, ground, site)
        rod = site.loop.actuators[1]
        return info.value, site, rod.tripped(), rod.feedback()


def test_a_specimen_softer_than_declared_stops_the_ramp_in_before_the_stroke():
    trip, site, controller_trip, held = ramp_in(soft_column())
    assert trip.kind == "preload_ramp" and trip.actuator == "axial" and exit_status(trip) == INTERLOCK
    message = str(trip)
    assert "the ramp in of static preload 'axial' was stopped" in message
    assert "measured rod displacement" in message and "(120.650 mm = 95% of +/-127 mm)" in message
    assert "softer than its declared K^EI = 50 kN/mm: measured secant 0.5" in message
    assert controller_trip is None  # the controller's own stroke interlock never fired
    phases = [p for p, *_ in site.static_log]
    assert phases and set(phases) == {"ramp_in"}  # no step of the record, no ramp off
    disps = np.array([d[0] for *_, d in site.static_log])
    forces = np.array([f[0] for _, _, _, f, _ in site.static_log])
    assert 0.95 * HALF_STROKE < disps[-1] < HALF_STROKE  # the period that tripped, logged last
    assert np.max(np.abs(disps)) < HALF_STROKE and abs(held.displacement_mm) < HALF_STROKE
    assert forces[-1] < 125.0 / 2  # stopped on the way: 0.5 kN/mm x ~121 mm
    assert forces[-1] / disps[-1] == pytest.approx(0.5, rel=0.02)  # the secant the message gives
    peaks = site.ramp_peaks["ramp_in"]["axial"]
    assert peaks["peak_stroke_mm"] == pytest.approx(disps[-1]) and peaks["peak_speed_mm_s"] < 0.95 * VELOCITY


def test_a_rod_driven_beyond_its_velocity_limit_stops_the_ramp():
    """100 kN in 0.2 s: over the declared 50 kN/mm the rod would move at tens of mm/s; over the
    real 0.5 kN/mm the force loop asks the valve for more than its flow and the rod runs at it."""
    trip, site, controller_trip, _ = ramp_in(soft_column("100.0", "0.2"))
    assert trip.kind == "preload_ramp" and controller_trip is None
    assert "measured rod speed" in str(trip) and "(475.0 mm/s = 95% of 500 mm/s)" in str(trip)
    peaks = site.ramp_peaks["ramp_in"]["axial"]
    assert 0.95 * VELOCITY < peaks["peak_speed_mm_s"] <= VELOCITY * 1.01  # the flow limit, read through the noise
    assert peaks["peak_stroke_mm"] < 10.0  # caught within the first hundredths of a second


def preloaded_run():
    structure = hsio.load_structure("preloaded_column")
    ground = hsio.synthetic_record(duration_s=0.5, dt=structure.dt, pga_g=0.3, seed=2)
    with hsio.open_site(structure, "emulator://", test_rate=10) as site:
        return hsio.simulate(structure, ground, site)


def test_a_correct_declaration_ramps_as_before(monkeypatch):
    """The watch only reads: the run equals one whose watch sees nothing, step for step."""
    watched = preloaded_run()
    monkeypatch.setattr(RampWatch, "__call__", lambda self, t, feedback: None)
    unwatched = preloaded_run()
    np.testing.assert_array_equal(watched.u, unwatched.u)
    assert len(watched.static_log) == len(unwatched.static_log)
    for a, b in zip(watched.static_log, unwatched.static_log):
        assert a[0] == b[0] and a[1] == b[1]
        for x, y in zip(a[2:], b[2:]):
            np.testing.assert_array_equal(x, y)
    assert set(watched.static_ramps) == {"ramp_in", "ramp_off"}
    ramp_in = watched.static_ramps["ramp_in"]["axial"]
    assert ramp_in["peak_stroke_mm"] == pytest.approx(125.0 / 50.0, abs=0.06)  # F / k, within the transducer's noise
    assert ramp_in["peak_speed_mm_s"] < 20.0  # ~3.8 mm/s predicted, plus the noise over 10 ms


def test_hsio_run_stops_a_soft_preload_as_an_interlock_and_records_it(tmp_path):
    (tmp_path / "soft.toml").write_text(LIBRARY.read_text().replace(
        'model = { kind = "linear", k = 50.0 }', 'K_EI = 50.0\nmodel = { kind = "linear", k = 0.5 }'))
    (tmp_path / "run.toml").write_text('[structure]\nfile = "soft.toml"\n[record]\nduration_s = 1.0\n'
                                       '[test]\nrate = 10.0\n[output]\nplots = false\n[safety]\nkeys = false\n')
    result = CliRunner().invoke(main, ["run", str(tmp_path / "run.toml"), "--out", str(tmp_path / "o")])
    assert result.exit_code == 4, result.output
    assert "interlock (preload_ramp) on actuator 'axial'" in result.output
    assert "the actuators hold (confirmed by read-back)" in result.output
    run = Run(tmp_path / "o" / "run.sqlite")
    events = run.events()
    assert [e["kind"] for e in events][-3:] == ["trip", "hold", "stop"]
    assert events[-3]["actuator"] == "axial" and run.summary["steps"] == 0
    peaks = run.summary["static_ramps"]["ramp_in"]["axial"]
    assert 0.95 * HALF_STROKE < peaks["peak_stroke_mm"] < HALF_STROKE
    static = run.table("static")  # the ramp's steps, the period that tripped last
    assert len(static["phase"]) > 1 and set(static["phase"]) == {0.0}
    assert static["disp_axial"][-1] == pytest.approx(peaks["peak_stroke_mm"])


class Feedback:
    def __init__(self, d, f=0.0):
        self.displacement_mm, self.force_kN = d, f


class Axis:
    def __init__(self, name):
        self.name, self.limits = name, Limits(stroke_mm=254.0, velocity_mm_s=500.0)


def watch(margins=(0.05, 0.05)):
    load = StaticLoad("axial", -100.0, {"kind": "linear", "k": 1.0}, 1.0, K_EI_declared=50.0)
    return RampWatch([load], [Axis("lateral"), Axis("axial")], 1, [(0.0, 0.0)], 0.0, "ramp_off", margins, 1 / 1000)


@pytest.mark.parametrize("speed, trips", [(470.0, False), (480.0, True), (-480.0, True)])
def test_the_watch_judges_the_speed_over_its_window_against_the_limit_less_the_margin(speed, trips):
    """A rod at constant speed: the slope over the 10 ms window is that speed; 475 mm/s is the
    limit (500) less 5 %."""
    w = watch()
    tripped = None
    for k in range(1, 40):
        t = k / 1000
        try:
            w(t, [Feedback(0.0), Feedback(speed * t, -k * 0.47)])
        except InterlockTrip as exc:
            tripped = (k, str(exc))
            break
    assert (tripped is not None) == trips
    if trips:
        assert tripped[0] == 10  # judged once the window holds 10 periods, not earlier on fewer
        assert "ramp off of static preload 'axial'" in tripped[1] and "measured rod speed 480.0 mm/s" in tripped[1]
    else:
        assert w.peaks()["axial"]["peak_speed_mm_s"] == pytest.approx(470.0)


def test_the_watch_takes_the_run_s_stroke_margin():
    w = watch(margins=(0.5, 0.05))  # a half of the stroke allowed: 63.5 mm
    w(0.001, [Feedback(0.0), Feedback(63.4)])
    with pytest.raises(InterlockTrip, match=r"63\.600 mm is beyond the stroke less the margin \(63\.500 mm = 50% of "
                                            r"\+/-127 mm\); likely cause: the rod moved \+63\.600 mm while the measured force "
                                            r"did not follow it as a spring's would \(secant 0 kN/mm"):
        w(0.002, [Feedback(0.0), Feedback(63.6)])


def test_K_EI_of_a_preload_is_read_and_checked():
    structure = soft_column()
    assert structure.static[0].K_EI == 50.0 and structure.static[0].model().initial_stiffness == 0.5
    assert hsio.load_structure("preloaded_column").static[0].K_EI == 50.0  # undeclared: the model's
    text = LIBRARY.read_text().replace("ramp_s = 2.0", "ramp_s = 2.0\nK_EI = -1.0")
    with pytest.raises(ConfigError, match=r"c\.toml: static\[0\]\.K_EI: must be positive"):
        parse_structure(text, "c.toml")


def test_a_specimen_that_fails_in_the_record_stops_the_ramp_off_and_the_record_says_so(tmp_path):
    """The axial member loses its stiffness at the record's last step (0.5 kN/mm left of 50): the
    force loop runs the rod out after its preload, and the ramp off stops as an interlock; the
    whole record is kept, with the trip, the hold and the stop."""
    from hsio.experiment import excitation
    from hsio.recording import Recorder
    from hsio.specimens import make_specimen
    from hsio.structures import channel_names

    structure = hsio.load_structure("preloaded_column")
    ground = hsio.synthetic_record(duration_s=0.3, dt=structure.dt, pga_g=0.3, seed=2)
    steps = len(excitation(structure, ground)[0]) - 1
    recorder = Recorder(tmp_path / "run.sqlite", structure.dof_names, channel_names(structure), {})
    # the sudden loss of force is not judged a load cell's jump here, and a tenth of the stroke is
    # allowed: the rod reaches it before the force-loop's following error has lasted 0.5 s
    safety = SafetySettings(jump_kN=1000.0, stroke_margin=0.9)
    with hsio.open_site(structure, "emulator://", test_rate=10, safety=safety) as site:
        axial = site.loop.actuators[1].controller
        done = []

        def crack(n):
            done.append(n)
            if len(done) == steps:
                axial.specimen = make_specimen({"kind": "linear", "k": 0.5})

        with pytest.raises(hsio.ExperimentStopped, match="ramp off of the static preloads") as info:
            hsio.simulate(structure, ground, site, recorder=recorder, progress=crack)
        assert axial.tripped == ""  # stopped before the controller's own stroke interlock
    recorder.close()
    stopped = info.value
    assert exit_status(stopped) == INTERLOCK and isinstance(stopped.cause, InterlockTrip)
    assert "preload_ramp" in str(stopped.cause) and "ramp off of static preload 'axial'" in str(stopped.cause)
    partial = stopped.result
    assert partial.steps == steps and [p for p, *_ in partial.static_log].count("test") == steps
    assert partial.static_log[-1][0] == "ramp_off" and "ramp_off" in partial.static_ramps
    events = Run(tmp_path / "run.sqlite").events()
    assert [e["kind"] for e in events][-3:] == ["trip", "hold", "stop"]


def test_a_preload_beyond_the_stroke_on_a_stiff_enough_specimen_is_named_as_such():
    """125 kN declared over 0.9 kN/mm asks 138.9 mm, beyond the 120.65 mm allowed; what it loads is
    stiffer (1 kN/mm), so the rod is where the force puts it: the message says the preload asks
    more stroke than allowed, not that the rod outran the force. A speed trip at that secant is
    the force loop's (the check before the ramp held the force rate over K^EI within the limit)."""
    load = StaticLoad("axial", 125.0, {"kind": "linear", "k": 1.0}, 1.0, K_EI_declared=0.9)
    w = RampWatch([load], [Axis("axial")], 0, [(0.0, 0.0)], 0.0, "ramp_in", (0.05, 0.05), 1 / 1000)
    w(0.001, [Feedback(120.0, 120.0)])
    with pytest.raises(InterlockTrip) as info:
        w(0.002, [Feedback(121.0, 121.0)])
    message = str(info.value)
    assert "beyond the stroke less the margin" in message and "not below the declared K^EI = 0.9 kN/mm" in message
    assert "the rod is where the force puts it; the preload of 125 kN over K^EI asks 138.889 mm" in message
    assert "force rate" not in message
    fast = RampWatch([load], [Axis("axial")], 0, [(0.0, 0.0)], 0.0, "ramp_in", (0.05, 0.05), 1 / 1000)
    with pytest.raises(InterlockTrip) as info:
        for k in range(1, 20):
            fast(k / 1000, [Feedback(0.5 * k, 0.5 * k)])  # 500 mm/s at a secant of 1 kN/mm
    assert "measured rod speed" in str(info.value) and "moves faster than the force rate asks" in str(info.value)
