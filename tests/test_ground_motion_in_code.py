"""Ground motions built in code and run through the API: another time step than the structure's is
resampled (linear interpolation), and a record whose accelerations were changed in place to a value
that is not a number is refused with what it is."""

from __future__ import annotations

import numpy as np
import pytest

import hsio
from hsio.errors import RecordError
from hsio.ground_motion import GroundMotion


def test_a_sample_set_to_nan_after_the_record_was_made_is_named_as_such():
    structure = hsio.load_structure("structure_I")
    ground = hsio.synthetic_record(duration_s=0.5, dt=structure.dt, seed=5)
    ground.accel_g[40] = np.nan
    with pytest.raises(RecordError, match=r"sample 40 \(t = 0\.200 s\) is nan, not a finite number$"):
        hsio.run_numerical(structure, ground)


def test_a_record_at_another_step_runs_as_its_linear_interpolation():
    """A sine at 0.025 s on a structure at 0.005 s: the run is that of the record interpolated to
    0.005 s, step for step, over the same duration."""
    structure = hsio.load_structure("structure_I")
    t = np.arange(0.0, 1.0 + 1e-9, 0.025)
    coarse = GroundMotion("sine", 0.025, 0.2 * np.sin(2 * np.pi * 2.0 * t))
    fine = GroundMotion("sine", structure.dt, np.interp(np.arange(201) * structure.dt, t, coarse.accel_g))
    a, b = hsio.run_numerical(structure, coarse), hsio.run_numerical(structure, fine)
    assert a.steps == b.steps == 200
    assert np.array_equal(a.u, b.u)
