"""The stand-alone emulated vRTHS plant: step response and agreement with the RTHS loop's plant."""

from __future__ import annotations

import numpy as np
import pytest

from hsio.emulators.vrths_plant import VrthsPlant
from hsio.rths import benchmark, plant
from hsio.rths.jit import jit


def test_step_response_settles_at_the_inner_loop_gain(shared_data):
    data = benchmark.load(str(shared_data / "vrths")).data
    p = plant.nominal(data)
    dev = VrthsPlant(p, noise_seed=1)
    for _ in range(4096):  # 1 s of a 1 mm step
        x_m, f_m = dev.step(1e-3)
    L = p.a1b0 / (p.b2 * p.a3 * p.ke)
    assert dev.displacement == pytest.approx(1e-3 * p.input_gain * L / (1 + L), rel=1e-3)
    assert dev.force == pytest.approx(p.ke * dev.displacement, rel=1e-3)  # static: F = k_e x
    assert abs(x_m - dev.displacement) < 5 * p.noise_V * p.m_per_V  # measured through the noise


def test_saturates_at_the_force_limit(shared_data):
    p = plant.nominal(benchmark.load(str(shared_data / "vrths")).data)
    dev = VrthsPlant(p)
    forces = [dev.step(20e-3) and dev.force for _ in range(2048)]  # 20 mm asks 24 kN
    assert max(abs(f) for f in forces) == pytest.approx(p.max_force)


def test_same_samples_as_the_plant_in_the_loop(shared_data):
    """Open loop through the RTHS kernel (a stage replaying a command) and through VrthsPlant."""
    from hsio.rths import loop
    from hsio.rths.stage import Stage

    bm = benchmark.load(str(shared_data / "vrths"))
    p = plant.perturbed(bm.data, 4, 1)[0]
    n = 2000
    cmd = 1e-3 * np.sin(2 * np.pi * 5 * np.arange(n) / benchmark.FS)
    stage = Stage("replay", _replay, cmd, np.zeros(1))
    sub = benchmark.numerical_substructure(benchmark.case(bm, 1))
    r = loop.run(stage, p, sub, np.zeros(n), benchmark.FS, noise_seed=0, use_numba=False)
    # the loop draws its displacement noise first, then the force noise; replay the same streams
    rng = np.random.default_rng(0)
    nx, nf = rng.normal(0, p.noise_V, n), rng.normal(0, p.noise_V, n)
    dev = VrthsPlant(p)
    dev.rng = _Replay(nx, nf)
    x0, _ = dev.measure()
    xs = [x0]
    for k in range(n - 1):
        xs.append(dev.step(cmd[k])[0])
    np.testing.assert_allclose(r.x_m, xs, rtol=0, atol=1e-15)


@jit
def _replay(p, s, k, x_t, v_t, a_t, x_m):
    return p[k]


class _Replay:
    """Stands in for the generator: hands out the displacement and force noise alternately."""

    def __init__(self, nx, nf):
        self.streams, self.i, self.turn = (nx, nf), 0, 0

    def normal(self, mean, std):
        v = self.streams[self.turn][self.i]
        self.turn ^= 1
        if self.turn == 0:
            self.i += 1
        return v


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf"), "1e-3", None])
def test_a_command_that_is_not_a_finite_number_is_refused_and_the_plant_holds(shared_data, bad):
    p = plant.nominal(benchmark.load(str(shared_data / "vrths")).data)
    dev = VrthsPlant(p)
    for _ in range(50):
        dev.step(1e-3)
    before = dev.w.copy()
    with pytest.raises(ValueError, match="VrthsPlant.step: the command must be a finite displacement in m"):
        dev.step(bad)
    np.testing.assert_array_equal(dev.w, before)
    dev.step(np.float64(1e-3))  # numpy scalars are numbers too
