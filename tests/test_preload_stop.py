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
