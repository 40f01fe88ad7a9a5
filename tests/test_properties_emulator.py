"""Property-based tests (hypothesis) of the emulated controller's settings: an [emulator] table
(of a run configuration or of an actuator-model file written by `hsio diagnose`) with any value
for any setting either builds a controller that steps, or is refused with a ConfigError naming
the setting (docs/faults.md). Bounded: a few seconds. Values at the edges are plain tests too."""

from __future__ import annotations

import dataclasses
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hsio.emulators.servo import ServoConfig, ServoController
from hsio.errors import ConfigError
from hsio.specimens import Linear

SETTINGS = [f.name for f in dataclasses.fields(ServoConfig)] + ["preset"]
values = st.one_of(
    st.sampled_from([0, -1, 0.0, 1e-300, 5e-324, 1e300, 10**30, True, "", "structure_I", [], {}, None]),
    st.floats(allow_nan=True), st.integers(-10**6, 10**6), st.floats(1e-6, 2e5), st.text(max_size=6),
)


@settings(max_examples=300, deadline=None)
@given(st.dictionaries(st.sampled_from(SETTINGS), values, min_size=1, max_size=3))
def test_emulator_settings_build_a_controller_that_steps_or_are_named(table):
    try:
        config = ServoConfig.from_dict(table)
    except ConfigError as exc:
        assert str(exc).startswith("emulator: ")
        return
    controller = ServoController(Linear(1.0), config)
    controller.advance(8)


@pytest.mark.parametrize("table, words", [
    ({"rate_hz": 1e300}, "emulator: rate_hz = 1e+300 is out of bounds: it must be within 10..100000 Hz"),
    ({"servo_frequency_hz": 1e-300}, "emulator: servo_frequency_hz = 1e-300 is out of bounds: 0 (no servo mode) or "
                                     "within 0.001..512 Hz"),
    ({"preset": []}, "emulator: unknown preset []"),
    ({"preset": {"a": 1}}, "emulator: unknown preset {'a': 1}"),
])
def test_settings_at_the_edges_of_their_range_are_named(table, words):
    with pytest.raises(ConfigError) as exc:
        ServoConfig.from_dict(table)
    assert str(exc.value).startswith(words)


def test_a_resolution_finer_than_a_float_leaves_the_reading_as_it_is():
    """5e-324 mm is a positive resolution; a reading divided by it is beyond the float range."""
    controller = ServoController(Linear(1.0), ServoConfig.from_dict({"resolution_mm": 5e-324, "noise_mm": 0.0,
                                                                     "force_resolution_kN": 5e-324}))
    controller.set_command(1.0)
    controller.advance(64)
    assert 0 < controller.measured_displacement < 1.0 and math.isfinite(controller.measured_force)


def test_the_slowest_servo_mode_allowed_filters_with_finite_coefficients():
    controller = ServoController(Linear(1.0), ServoConfig.from_dict({"servo_frequency_hz": 1e-3}))
    controller.advance(64)
    assert all(math.isfinite(v) for part in controller._mode for v in part)
