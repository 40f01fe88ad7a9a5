"""A preload at its actuator's capacity: the command stays exactly on it, and a trip of the
controller in force control is reported as the trip (docs/setups.md, static actuators)."""

from pathlib import Path

import pytest

import hsio
from hsio.command import PredictorCorrector
from hsio.structure_file import parse_structure


@pytest.mark.parametrize("value", [250.0, 249.9, 123.456, -250.0, 0.1])
def test_a_segment_between_equal_commands_at_rest_stays_exactly_on_them(value):
    """A held target (a preload, every step the same) is interpolated from itself to itself: each
    sample is the target exactly, never 1 ulp beyond it (250.00000000000003 kN would be refused
    against a 250 kN capacity that the preload itself passed)."""
    g = PredictorCorrector(t_d=0.1, period=1 / 1024, initial=value)
    for _ in range(5):
        g.new_target(value)
        for _ in range(g.planned_samples()):
            assert g.next_sample() == value


def test_a_controller_tripped_in_force_control_is_reported_as_its_trip():
    """A preload exactly at the capacity trips the emulated controller on its load cell's noise;
    the tripped controller holds in displacement control, and its next force command (250, beyond
    the 127 mm stroke read as a displacement) must not be reported as a displacement command beyond
    the stroke. The run stops naming the trip."""
    text = (Path(hsio.__file__).parent / "library" / "preloaded_column.toml").read_text()
    structure = parse_structure(text.replace("force_kN = 125.0", "force_kN = 250.0").replace("ramp_s = 2.0", "ramp_s = 0.5"),
                                "at_capacity.toml")
    ground = hsio.synthetic_record(duration_s=0.5, dt=structure.dt, pga_g=0.3, seed=2)
    with hsio.open_site(structure, "emulator://", test_rate=10) as site:
        with pytest.raises(hsio.experiment.ExperimentStopped) as stopped:
            hsio.simulate(structure, ground, site)
    message = str(stopped.value)
    assert "actuator 'axial': interlock tripped: force" in message and "beyond the capacity" in message
    assert "stroke" not in message
