"""Relative trials (the specimen's position when the site opens is zero) and the initial read-back
of every channel (docs/setups.md)."""

import numpy as np
import pytest

import hsio
from hsio.api import format_readback
from hsio.clock import LockstepClock
from hsio.control_loop import ControlLoop
from hsio.emulators.local import open_instruments, open_url
from hsio.result import max_error_pct
from hsio.sites import ActuatorSite
from hsio.specimens import Linear
from hsio.structure_file import parse_structure

TEXT = """
[structure]
dt = 0.01
[[dof]]
name = "x"
mass = 0.01
[damping]
kind = "mass"
zeta = 0.05
[[experimental]]
name = "x"
dof = "x"
model = { kind = "linear", k = 1.5 }
[[instrument]]
name = "x_pot"
kind = "string_pot"
element = "x"
"""


class Installed(Linear):
    """A linear specimen installed (unstressed) with the actuator at ``at`` mm."""

    def __init__(self, k: float, at: float):
        super().__init__(k)
        self.at = at

    def trial(self, u: float, dt: float = 0.0) -> float:
        return super().trial(u - self.at, dt)


def site_after_an_offset(offset_mm: float, relative: bool, installed: bool = True):
    structure = parse_structure(TEXT, "offset.toml")
    clock = LockstepClock()
    actuators = open_url("emulator://", structure.experimental, clock, {"noise_mm": 0.0, "resolution_mm": 0.0})
    controller = actuators[0].controller
    if installed:
        controller.specimen = Installed(1.5, offset_mm)
    controller.set_command(offset_mm)  # where the specimen stands when the test begins
    controller.advance(600)
    loop = ControlLoop(actuators, clock, structure.dt, 10.0, n_avg=4, hold_fraction=0.5)
    daq = open_instruments(structure.instruments, structure.experimental, actuators)
    return structure, controller, ActuatorSite(loop, instruments=daq, external=[None], relative=relative)


def test_relative_trials_start_from_the_position_at_enabling():
    structure, controller, site = site_after_an_offset(7.5, relative=True)
    ground = hsio.synthetic_record(duration_s=1.5, dt=structure.dt, pga_g=0.3, seed=3)
    ns = hsio.run_numerical(structure, ground)
    with site:
        assert site.zero[0] == pytest.approx(7.5, abs=1e-3)
        assert site.committed()[0][0] == pytest.approx(0.0, abs=1e-3)
        hs = hsio.simulate(structure, ground, site)
    # the specimen moved about its starting position: the record is relative, the rod absolute
    assert max_error_pct(hs.u, ns.u)[0] < 3.0
    assert controller.d_rod == pytest.approx(7.5 + hs.commands[-1, 0], abs=0.05)
    assert abs(hs.measured_displacement[1, 0]) < 1.0  # not 7.5
    readings = np.array([r["x_pot"] for _, _, r in hs.instrument_log])
    np.testing.assert_allclose(readings - 7.5, hs.measured_displacement[1:, 0], atol=0.02)


def test_initial_readback_of_every_channel():
    _, controller, site = site_after_an_offset(-4.0, relative=False, installed=False)
    with site:
        back = site.readback
        assert set(back) == {"x.displacement", "x.force", "x_pot"}
        assert back["x.displacement"] == pytest.approx(-4.0, abs=1e-3)
        assert back["x_pot"] == pytest.approx(-4.0, abs=1e-3)
        assert back["x.force"] == pytest.approx(-6.0, abs=0.01)
        assert site.zero[0] == 0.0  # absolute trials
        text = format_readback(back, {"x_pot": "mm"})
        assert text.splitlines()[0].split() == ["channel", "value", "unit"]
        assert "x.force" in text and "-6.0" in text and text.count("\n") == 3
