"""The interlocks of the control loop, the hold read-back and the [safety] ranges, period by
period on given samples (no emulator): each threshold as documented in docs/config.md ([safety])
and in the docstrings of hsio.safety - strict inequalities, timers that restart, one warning per
entry into a band, the force-drop envelope - and the words an operator reads."""

from __future__ import annotations

from dataclasses import asdict

import pytest

from hsio.errors import ConfigError
from hsio.interfaces import ControlMode, Feedback, Limits
from hsio.safety.hold import HoldReport, read_back
from hsio.safety.interlocks import InterlockMonitor
from hsio.safety.settings import DEFAULTS, SafetySettings, check_table
from hsio.safety.status import InterlockTrip

DC, FC = ControlMode.DISPLACEMENT, ControlMode.FORCE
DT = 0.125  # a controller period exact in binary: the timers are compared without rounding


class _Actuator:
    def __init__(self, name, limits=None):
        self.name = name
        self.limits = limits or Limits(stroke_mm=200.0, force_kN=100.0)


def _monitor(n=1, **settings):
    return InterlockMonitor([_Actuator(f"A{e}") for e in range(n)], SafetySettings(**settings))


def _fb(d, f=0.0):
    return Feedback(displacement_mm=d, force_kN=f, time_s=0.0)


def _run(mon, samples, modes=None):
    """samples: (command, displacement, force) per period for actuator A0; returns the period
    index of the trip and the trip, or (None, None)."""
    for i, (c, d, f) in enumerate(samples):
        try:
            mon.check(i * DT, [c], [_fb(d, f)], modes or [DC])
        except InterlockTrip as trip:
            return i, trip
    return None, None


# -- following error ------------------------------------------------------------------------------
def test_following_error_at_the_threshold_never_trips():
    mon = _monitor(following_error_mm=2.0, following_time_s=0.5)
    assert _run(mon, [(2.0, 0.0, 0.0)] * 40) == (None, None)
    assert _run(mon, [(-2.0, 0.0, 0.0)] * 40) == (None, None)


def test_following_error_trips_only_after_the_time():
    """Beyond the threshold from t = 0: |error| > limit for longer than following_time_s trips,
    not at exactly that time (t = 0.5 s), at the next period."""
    mon = _monitor(following_error_mm=2.0, following_time_s=0.5)
    i, trip = _run(mon, [(0.0, 2.5, 0.0)] * 40)
    assert i * DT == 0.625
    assert trip.kind == "following" and trip.actuator == "A0"
    text = str(trip)
    assert "interlock (following) on actuator 'A0' at t = 0.6250 s" in text
    assert "command - measured = -2.500 mm beyond 2 mm for 0.625 s (limit 0.5 s)" in text
    events = mon.take_events()
    assert [e["kind"] for e in events] == ["trip"] and events[0]["message"] == text
    assert events[0]["time_s"] == 0.625 and events[0]["actuator"] == "A0"
    assert mon.take_events() == []


def test_following_timer_restarts_when_the_error_comes_back():
    """0.375 s beyond, one period within, 0.375 s beyond, ...: never longer than 0.5 s on end."""
    mon = _monitor(following_error_mm=2.0, following_time_s=0.5)
    cycle = [(3.0, 0.0, 0.0)] * 4 + [(1.0, 0.0, 0.0)]
    assert _run(mon, cycle * 10) == (None, None)
    # and without the period within, the same error trips
    i, trip = _run(_monitor(following_error_mm=2.0, following_time_s=0.5), [(3.0, 0.0, 0.0)] * 10)
    assert trip is not None and i == 5


def test_following_message_gives_the_time_beyond_since_the_error_began():
    """Within until t = 1 s, beyond from then on: the trip at t = 1.625 s says 0.625 s."""
    mon = _monitor(following_error_mm=2.0, following_time_s=0.5)
    i, trip = _run(mon, [(0.0, 0.0, 0.0)] * 8 + [(0.0, 2.5, 0.0)] * 10)
    assert i * DT == 1.625 and "beyond 2 mm for 0.625 s (limit 0.5 s)" in str(trip)


def test_following_error_zero_time_trips_at_the_second_period_beyond():
    mon = _monitor(following_error_mm=2.0, following_time_s=0.0)
    i, trip = _run(mon, [(0.0, 0.0, 0.0), (3.0, 0.0, 0.0), (3.0, 0.0, 0.0)])
    assert i == 2 and trip.kind == "following"


def test_force_control_compares_force_with_the_kn_threshold():
    """In FC the error is command - measured force against following_error_kN; the displacement
    (far from the force command, as it always is) does not count."""
    mon = _monitor(following_error_mm=1.0, following_error_kN=5.0, following_time_s=0.25)
    assert _run(mon, [(50.0, 0.3, 46.0)] * 20, [FC]) == (None, None)  # 4 kN off, 49.7 'mm' off
    i, trip = _run(_monitor(following_error_mm=1.0, following_error_kN=5.0, following_time_s=0.25),
                   [(50.0, 0.3, 44.0)] * 20, [FC])
    assert i * DT == 0.375 and "command - measured = 6.000 kN beyond 5 kN" in str(trip)
    # and in DC the force does not count
    assert _run(_monitor(following_error_mm=1.0, following_error_kN=5.0, following_time_s=0.25),
                [(0.3, 0.3, 80.0)] * 20, [DC]) == (None, None)


def test_each_actuator_has_its_own_timer():
    mon = _monitor(2, following_error_mm=2.0, following_time_s=0.25)
    for i in range(3):  # A0 beyond for 0.25 s, A1 within
        mon.check(i * DT, [3.0, 0.0], [_fb(0.0), _fb(0.0)], [DC, DC])
    with pytest.raises(InterlockTrip) as e:
        for i in range(3, 6):  # now A1 beyond: its own timer starts
            mon.check(i * DT, [3.0, 3.0], [_fb(0.0), _fb(0.0)], [DC, DC])
    assert e.value.actuator == "A0"


# -- implausible measurements -----------------------------------------------------------------------
@pytest.mark.parametrize("d, f", [(float("nan"), 0.0), (0.0, float("inf")), (float("-inf"), 0.0)])
def test_a_measurement_that_is_not_a_number_trips(d, f):
    mon = _monitor()
    with pytest.raises(InterlockTrip, match="not a finite number") as e:
        mon.check(0.0, [0.0], [_fb(d, f)], [DC])
    assert e.value.kind == "not_finite"


def test_jumps_trip_beyond_the_limit_only():
    """A jump of exactly jump_mm / jump_kN between two periods is plausible; beyond, a trip that
    says which transducer."""
    mon = _monitor(jump_mm=1.0, jump_kN=10.0, following_error_mm=1e9, following_error_kN=1e9)
    assert _run(mon, [(0.0, 0.0, 0.0), (0.0, 1.0, 10.0), (0.0, 0.0, 0.0), (0.0, -1.0, -10.0)]) == (None, None)
    i, trip = _run(_monitor(jump_mm=1.0, jump_kN=10.0, following_error_mm=1e9),
                   [(0.0, 0.0, 0.0), (0.0, 1.25, 0.0)])
    assert i == 1 and trip.kind == "jump"
    assert "measured displacement jumped by 1.250 mm in one controller period (limit 1 mm)" in str(trip)
    i, trip = _run(_monitor(jump_mm=1.0, jump_kN=10.0, following_error_mm=1e9),
                   [(0.0, 0.0, 0.0), (0.0, 0.0, -12.5)])
    assert i == 1 and trip.kind == "jump"
    assert "measured force jumped by 12.500 kN in one controller period (limit 10 kN)" in str(trip)


def test_force_jump_is_the_change_from_the_previous_force():
    """50 kN then 55 kN is a change of 5 kN (jump_kN 10), whatever the level; -50 then -45 too."""
    mon = _monitor(jump_kN=10.0, following_error_mm=1e9)
    assert _run(mon, [(0.0, 0.0, 50.0), (0.0, 0.0, 55.0), (0.0, 0.0, 60.0)]) == (None, None)
    assert _run(_monitor(jump_kN=10.0, following_error_mm=1e9),
                [(0.0, 0.0, -50.0), (0.0, 0.0, -45.0)]) == (None, None)


def test_jump_is_measured_from_the_previous_period_not_the_first():
    """A slow drift of 0.9 mm per period (jump_mm 1) goes far without a trip."""
    mon = _monitor(jump_mm=1.0, following_error_mm=1e9)
    assert _run(mon, [(0.0, 0.9 * i, 0.0) for i in range(50)]) == (None, None)


# -- warning bands ------------------------------------------------------------------------------------
def test_warning_once_per_entry_into_the_band():
    """|d| beyond warning_fraction of the half stroke (100 mm here) and |F| beyond that fraction of
    the capacity (100 kN): a warning on entry, none while inside, another on re-entry; never a trip."""
    mon = _monitor(warning_fraction=0.9, following_error_mm=1e9, jump_mm=1e9, jump_kN=1e9)
    seq = [(0.0, 90.0, 0.0),  # at 90 % exactly: not beyond
           (0.0, 91.0, 0.0), (0.0, 95.0, 0.0), (0.0, -95.0, 0.0),  # one entry (|d|)
           (0.0, 10.0, 0.0), (0.0, -91.0, 0.0),  # out, and in again
           (0.0, 0.0, -90.5), (0.0, 0.0, -99.0), (0.0, 0.0, 50.0), (0.0, 0.0, 95.0)]  # force: two entries
    for i, (c, d, f) in enumerate(seq):
        mon.check(i * DT, [c], [_fb(d, f)], [DC])
    events = mon.take_events()
    assert mon.warnings == 4 == len(events)
    assert all(e["kind"] == "warning" and e["actuator"] == "A0" for e in events)
    assert [e["time_s"] for e in events] == [1 * DT, 5 * DT, 6 * DT, 9 * DT]
    assert events[0]["message"] == "displacement 91.000 mm beyond 90% of the limit (+/-100 mm)"
    assert events[2]["message"] == "force -90.500 kN beyond 90% of the limit (+/-100 kN)"


def test_a_run_that_starts_inside_the_band_is_warned_at_once():
    """A preloaded specimen: the first period is already beyond the band (displacement and force):
    one warning each, at t = 0."""
    mon = _monitor(warning_fraction=0.9)
    mon.check(0.0, [95.0], [_fb(95.0, -96.0)], [DC])
    mon.check(DT, [95.0], [_fb(95.0, -96.0)], [DC])
    events = mon.take_events()
    assert [(e["time_s"], e["message"].split()[0]) for e in events] == [(0.0, "displacement"), (0.0, "force")]
    assert mon.warnings == 2


def test_events_kept_are_bounded_and_the_oldest_dropped():
    """A run that enters and leaves the band for ever keeps going, its memory bounded: the last
    MAX_EVENTS warnings are kept, every warning is counted."""
    mon = _monitor(warning_fraction=0.5, following_error_mm=1e9, jump_mm=1e9)
    n = InterlockMonitor.MAX_EVENTS + 5
    for i in range(2 * n):
        d = 60.0 if i % 2 == 0 else 0.0
        mon.check(float(i), [d], [_fb(d)], [DC])
    assert mon.warnings == n
    events = mon.take_events()
    assert len(events) == InterlockMonitor.MAX_EVENTS
    assert events[0]["time_s"] == 10.0 and events[-1]["time_s"] == 2.0 * (n - 1)


# -- specimen failure (force drop) ----------------------------------------------------------------------
def _drop_monitor(**kw):
    s = dict(force_drop_fraction=0.5, force_drop_min_kN=10.0, force_drop_window_s=1.0,
             following_error_mm=1e9, jump_kN=1e9)
    s.update(kw)
    return _monitor(**s)


def test_force_drop_trips_when_the_envelope_falls_below_the_fraction_of_the_peak():
    """Peak 40 kN at t = 0; then 15 kN (below 50 % of 40): the envelope over the last 1 s still
    holds the peak until it leaves the window; the trip comes at the first period whose window no
    longer holds anything at or above 20 kN, and not before a full window after the peak."""
    mon = _drop_monitor()
    samples = [(0.0, 0.0, 40.0)] + [(0.0, 0.0, 15.0)] * 30
    i, trip = _run(mon, samples)
    assert trip.kind == "force_drop"
    assert i * DT == 1.125  # the peak (t = 0) leaves the window [t - 1, t] after t = 1
    assert "force envelope 15.000 kN over the last 1 s is below 50% of the peak 40.000 kN" in str(trip)


def test_force_drop_envelope_is_the_largest_force_in_the_window():
    """Cycles whose peaks stay at 30 kN (above half of 40): the envelope holds, no trip, although
    the force passes through zero every cycle."""
    mon = _drop_monitor()
    cycle = [(0.0, 0.0, f) for f in (0.0, 15.0, 30.0, 15.0, 0.0, -15.0, -30.0, -15.0)]  # 1 s per cycle
    assert _run(mon, [(0.0, 0.0, 40.0)] + cycle * 5) == (None, None)
    # the same cycles at 18 kN trip (envelope below 20)
    small = [(0.0, 0.0, f) for f in (0.0, 9.0, 18.0, 9.0, 0.0, -9.0, -18.0, -9.0)]
    i, trip = _run(_drop_monitor(), [(0.0, 0.0, 40.0)] + small * 5)
    assert trip is not None and trip.kind == "force_drop" and 1.0 < i * DT <= 1.25


def test_force_drop_waits_for_a_full_window_after_a_new_peak():
    mon = _drop_monitor()
    # 12 kN for 2 s, then a new peak of 40 kN at t = 2, then 0: no trip before t = 3
    samples = [(0.0, 0.0, 12.0)] * 16 + [(0.0, 0.0, 40.0)] + [(0.0, 0.0, 0.0)] * 20
    i, trip = _run(mon, samples)
    assert trip is not None and i * DT == 3.125


def test_force_drop_needs_the_peak_above_the_minimum():
    """A peak below force_drop_min_kN (noise about zero) arms nothing; at the minimum it does."""
    assert _run(_drop_monitor(), [(0.0, 0.0, 9.9)] + [(0.0, 0.0, 0.0)] * 30) == (None, None)
    i, trip = _run(_drop_monitor(), [(0.0, 0.0, 10.0)] + [(0.0, 0.0, 0.0)] * 30)
    assert trip is not None and trip.kind == "force_drop"


def test_force_drop_with_no_minimum_arms_on_any_peak():
    """force_drop_min_kN = 0: a small specimen's peak of 0.8 kN, then nothing: a trip."""
    i, trip = _run(_drop_monitor(force_drop_min_kN=0.0),
                   [(0.0, 0.0, 0.0), (0.0, 0.0, 0.8)] + [(0.0, 0.0, 0.0)] * 30)
    assert trip is not None and trip.kind == "force_drop" and "peak 0.800 kN" in str(trip)


def test_force_drop_is_off_by_default():
    assert _run(_monitor(following_error_mm=1e9, jump_kN=1e9),
                [(0.0, 0.0, 40.0)] + [(0.0, 0.0, 0.0)] * 30) == (None, None)


def test_force_drop_at_exactly_the_fraction_does_not_trip():
    assert _run(_drop_monitor(), [(0.0, 0.0, 40.0)] + [(0.0, 0.0, 20.0)] * 30) == (None, None)


# -- hold confirmation ----------------------------------------------------------------------------------
def test_hold_is_confirmed_only_when_every_actuator_reads_back_holding():
    assert HoldReport({"A": True, "B": True}).confirmed
    assert HoldReport({"A": True, "B": True}).message == "the actuators hold (confirmed by read-back)"
    for states in ({"A": True, "B": None}, {"A": True, "B": False}, {}):
        assert not HoldReport(states).confirmed
    assert HoldReport({}).message == "no actuators were open"


def test_hold_message_names_each_actuator_by_state():
    r = HoldReport({"A": False, "B": None, "C": True, "D": None})
    assert r.message == ("WARNING: A did not confirm the hold (reads back not holding); "
                         "the hold of B, D could not be confirmed (no read-back); C hold (confirmed)")
    assert r.as_dict() == {"confirmed": False, "states": {"A": False, "B": None, "C": True, "D": None},
                           "message": r.message}
    assert HoldReport({"A": True}).as_dict()["confirmed"] is True


class _Holder:
    def __init__(self, name, answer):
        self.name, self.answer = name, answer

    def holding(self):
        if isinstance(self.answer, Exception):
            raise self.answer
        return self.answer


def test_read_back_counts_an_error_as_cannot_tell_and_never_as_holding():
    r = read_back([_Holder("A", 1), _Holder("B", 0), _Holder("C", None), _Holder("D", OSError("link lost"))])
    assert r.states == {"A": True, "B": False, "C": None, "D": None}
    assert not r.confirmed
    assert read_back([_Holder("A", True), _Holder("B", 1)]).confirmed


# -- [safety] settings ----------------------------------------------------------------------------------
def test_defaults_table_matches_the_settings():
    """The defaults written in the [safety] table (docs/config.md) are those of SafetySettings."""
    assert DEFAULTS == asdict(SafetySettings())
    assert SafetySettings.from_table(None) == SafetySettings()
    s = SafetySettings.from_table({"jump_mm": 3.0, "not_a_key": 1})
    assert s.jump_mm == 3.0 and s.following_error_mm == DEFAULTS["following_error_mm"]


@pytest.mark.parametrize("key, ok, bad", [
    ("stroke_margin", [0.0, 0.99], [-0.01, 1.0]),
    ("force_margin", [0.0, 0.5], [1.0, -1.0]),
    ("velocity_margin", [0.0, 0.5], [1.0, -0.5]),
    ("following_error_mm", [1e-6], [0.0, -1.0]),
    ("following_error_kN", [1e-6], [0.0]),
    ("jump_mm", [1e-6], [0.0]),
    ("jump_kN", [1e-6], [0.0]),
    ("force_drop_window_s", [1e-6], [0.0]),
    ("following_time_s", [0.0, 2.0], [-0.1]),
    ("warning_fraction", [1.0, 0.01], [0.0, 1.01]),
    ("force_drop_fraction", [0.0, 0.99], [1.0, -0.1]),
    ("force_drop_min_kN", [0.0, 5.0], [-0.1]),
])
def test_safety_ranges_at_their_ends(key, ok, bad):
    for value in ok:
        check_table({**DEFAULTS, key: value}, "lab.toml: [safety]")
    for value in bad:
        with pytest.raises(ConfigError, match=rf"lab.toml: \[safety\]: {key} must"):
            check_table({**DEFAULTS, key: value}, "lab.toml: [safety]")
