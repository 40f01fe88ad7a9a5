"""A Result as a notebook shows it: a one-line repr, and the logs of preloads and instruments as
typed fields, kept on the partial result of a run that stopped."""

import numpy as np
import pytest

import hsio


def test_a_result_shows_as_one_short_line():
    structure = hsio.load_structure("three_storey")
    ns = hsio.run_numerical(structure, hsio.synthetic_record(duration_s=10.0, dt=structure.dt, pga_g=0.1, seed=2))
    text = repr(ns)
    assert "\n" not in text and len(text) < 300
    assert text.startswith("Result(structure='three_storey', method='alpha_os', steps=2000, dt=0.005,")
    assert ns.instrument_log == [] and ns.static_log == [] and ns.static_hold_error is None


def test_a_stopped_run_keeps_the_preload_log_on_its_partial_result():
    structure = hsio.load_structure("preloaded_column")
    ground = hsio.synthetic_record(duration_s=2.0, dt=structure.dt, pga_g=0.9, seed=1)
    with pytest.raises(hsio.ExperimentStopped) as info:
        with hsio.open_site(structure, "emulator://", options={"stroke_mm": 15.0}) as site:
            hsio.simulate(structure, ground, site)
    partial = info.value.result
    assert 0 < partial.steps < 200 and "stopped=" in repr(partial)
    phases = [phase for phase, *_ in partial.static_log]
    assert phases[0] == "ramp_in" and phases[-1] == "test" and "ramp_off" not in phases  # held, not ramped off
    assert phases.count("test") == partial.steps  # every step made
    assert partial.static_hold_error[0] < 0.01
    assert np.all(np.isfinite(partial.static_hold_error))
