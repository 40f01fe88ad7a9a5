"""`simulate(..., start="present")` with a method that has no present start (the implicit
methods) is bad input: a ConfigError before anything is sent, and the site goes on serving."""

from __future__ import annotations

import numpy as np
import pytest

import hsio
from hsio.errors import ConfigError


@pytest.mark.parametrize("method", ["implicit_dc", "force_control", "mixed"])
def test_a_present_start_of_an_implicit_method_is_refused_before_anything_moves(method):
    structure = hsio.load_structure("validation")
    ground = hsio.synthetic_record(duration_s=0.2, dt=structure.dt, pga_g=0.3, seed=5)
    with hsio.open_site(structure, "emulator://", options={"noise_mm": 0.0}) as site:
        first = hsio.simulate(structure, ground, site)
        with pytest.raises(ConfigError, match=rf"^simulate: start = 'present' is available for the alpha_os method, "
                                              rf"not '{method}'.*nothing moved$"):
            hsio.simulate(structure, ground, site, method=method, start="present")
        second = hsio.simulate(structure, ground.scaled(0.0), site, start="present")
    assert second.steps == first.steps
    assert np.allclose(second.measured_displacement[0], first.measured_displacement[-1], atol=1e-9)
