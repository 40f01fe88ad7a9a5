"""The stuck-transducer check of the drivers' plausibility (docs/faults.md): the same displacement
reading, bit for bit, for stuck_samples samples in a row while the command's range since the
reading froze exceeds stuck_mm."""

from __future__ import annotations

import math

import pytest

from drivers import common
from hsio.errors import ImplausibleMeasurementError
from hsio.interfaces import Limits


def frozen(amplitude_mm: float, centre_mm: float = 0.0, samples: int = 4096, stuck_mm: float = 5.0):
    """A reading frozen at 0 mm while the command oscillates about ``centre_mm`` (1 Hz at 1024 Hz)."""
    check = common.Plausibility("C1", Limits(254.0, 250.0, 500.0), 1 / 1024,
                                {"stuck_samples": 512, "stuck_mm": stuck_mm})
    for k in range(samples):
        check.check(0.0, 0.0, k / 1024, centre_mm + amplitude_mm * math.sin(2 * math.pi * k / 1024))


def test_a_command_swinging_more_than_stuck_mm_about_the_frozen_reading_trips():
    """+/-4 mm about where the reading froze: the command never stands 5 mm from where it stood
    when the reading froze, but it moved over 8 mm."""
    with pytest.raises(ImplausibleMeasurementError, match="stuck transducer"):
        frozen(4.0)


def test_a_command_moving_away_trips():
    with pytest.raises(ImplausibleMeasurementError, match="stuck transducer"):
        frozen(8.0, centre_mm=0.0)


def test_a_command_moving_less_than_stuck_mm_is_left_to_the_other_interlocks():
    frozen(2.4)  # a 4.8 mm range: a still reading may be a quantised transducer; not judged here


def frozen_force(amplitude_mm: float, samples: int = 2048, options: dict | None = None):
    """A force reading frozen at 3 kN while the measured displacement oscillates (1 Hz at 1024 Hz)."""
    check = common.Plausibility("C1", Limits(254.0, 250.0, 500.0), 1 / 1024, options)
    for k in range(samples):
        d = amplitude_mm * math.sin(2 * math.pi * k / 1024)
        check.check(d, 3.0, k / 1024, d)


def test_a_force_frozen_while_the_specimen_moves_trips_as_a_stuck_load_cell():
    with pytest.raises(ImplausibleMeasurementError, match=r"force stuck at 3 kN for \d+ samples while the displacement "
                                                          r"moved over .* a stuck or saturated load cell"):
        frozen_force(0.6)  # a 1.2 mm range, past force_stuck_mm (1 mm)


def test_a_force_frozen_while_the_displacement_stays_within_force_stuck_mm_is_not_judged():
    frozen_force(0.45)  # 0.9 mm: a plateau, or a specimen at rest, cannot be told from a dead load cell
    frozen_force(0.6, options={"force_stuck_samples": 0})  # off
    with pytest.raises(ImplausibleMeasurementError, match="force stuck"):
        frozen_force(0.3, options={"force_stuck_mm": 0.5})  # a stiff specimen's test: lowered


def test_a_noisy_load_cell_on_a_moving_specimen_never_trips():
    """The last digit of a real load cell moves: a plateau with 0.002 kN of noise, read to 0.001 kN."""
    import numpy as np

    rng = np.random.default_rng(5)
    check = common.Plausibility("C1", Limits(254.0, 250.0, 500.0), 1 / 1024)
    for k in range(8192):
        d = 10.0 * math.sin(2 * math.pi * k / 1024)
        check.check(d, round(50.0 + rng.normal(0, 0.002), 3), k / 1024, d)


def test_a_force_held_in_force_control_is_never_a_stuck_load_cell():
    """In force control (no displacement command) the loop holds the force reading still while the
    stroke drifts, as a preload actuator's does with the structure: not judged."""
    check = common.Plausibility("preload", Limits(254.0, 500.0, 500.0), 1 / 1024)
    for k in range(4096):
        check.check(2.0 * math.sin(2 * math.pi * k / 1024), 200.0, k / 1024, None)


def test_counts_from_before_force_control_do_not_carry_over():
    """499 equal readings in displacement control, a spell of force control (the force moves), then
    displacement control again: both counts start afresh, nothing trips."""
    check = common.Plausibility("C1", Limits(254.0, 250.0, 500.0), 1 / 1024)
    t = 0
    for _ in range(499):
        check.check(0.0, 3.0, t / 1024, 0.0)
        t += 1
    for k in range(2000):
        check.check(0.0, 3.0 + 2.0 * k / 1999, t / 1024, None)  # ends at 5 kN, where the next readings stay
        t += 1
    for k in range(100):
        d = 0.03 * k
        check.check(d, 5.0, t / 1024, d)
        t += 1


def test_the_stuck_transducer_count_starts_afresh_after_force_control():
    """499 equal displacement readings while the command swings 6 mm, a spell of force control,
    then the same reading again under a swinging command: 100 samples, not 512, since the spell."""
    check = common.Plausibility("C1", Limits(254.0, 250.0, 500.0), 1 / 1024)
    t = 0
    for _ in range(499):
        check.check(0.0, 0.001 * t, t / 1024, 6.0 * (t % 2))
        t += 1
    for _ in range(50):
        check.check(0.0, 0.001 * t, t / 1024, None)
        t += 1
    for _ in range(100):
        check.check(0.0, 0.001 * t, t / 1024, 6.0 * (t % 2))
        t += 1
