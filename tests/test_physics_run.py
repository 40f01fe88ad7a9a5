"""`hsio run` integrates with the configured alpha: a linear SDOF under a constant ground
acceleration, run from a structure file on ideal emulated actuators, against the closed-form
solution of the alpha method (docs/method.md section 2)."""

import numpy as np
import pytest

from hsio import config as config_mod
from hsio import runner
from hsio.ground_motion import G_MM_S2, GroundMotion
from hsio.recording import Run

M, K, DT, A_G = 0.01, 1.0, 0.05, 0.1  # kN s^2/mm, kN/mm, s, g: omega = 10 rad/s, omega dt = 0.5

SDOF = f"""
[structure]
name = "sdof_step"
dt = {DT}

[[dof]]
name = "x"
mass = {M}

[damping]
kind = "mass"
zeta = 0.0

[[experimental]]
dof = "x"
model = {{ kind = "linear", k = {K} }}
"""

IDEAL = {"lag_s": 0.002, "noise_mm": 0.0, "resolution_mm": 0.0, "force_noise_kN": 0.0, "force_resolution_kN": 0.0}


def trapezoidal_step_response(n: int) -> np.ndarray:
    """alpha = 0 (average acceleration) on an undamped SDOF from rest under a constant ground
    acceleration a_g: u_n = u_st (1 - cos n theta), u_st = -a_g / omega^2 (the ground pushes the
    mass back), tan(theta / 2) = omega dt / 2 (the method's period elongation)."""
    omega = np.sqrt(K / M)
    u_st = -A_G * G_MM_S2 / omega**2
    theta = 2.0 * np.arctan(omega * DT / 2.0)
    return u_st * (1.0 - np.cos(np.arange(n) * theta))


@pytest.mark.parametrize("alpha", [0.0, -0.05])
def test_hsio_run_uses_the_configured_alpha(tmp_path, alpha):
    (tmp_path / "sdof.toml").write_text(SDOF)
    cfg = config_mod.from_dict({
        "structure": {"file": str(tmp_path / "sdof.toml")},
        "integrator": {"alpha": alpha},
        "test": {"rate": 5.0},
        "emulator": IDEAL,
        "output": {"plots": False, "samples": False},
        "safety": {"dry_run": False},
    })
    ground = GroundMotion("constant", DT, np.full(int(round(1.5 / DT)) + 1, A_G))
    runner.run(cfg, tmp_path / "run", ground=ground)
    run = Run(tmp_path / "run" / "run.sqlite")
    u_ns = run.ns["u_x"]
    u_hs = np.r_[0.0, run.steps["u_x"]]  # the steps table starts at step 1; u_0 = 0 (from rest)
    exact = trapezoidal_step_response(len(u_hs))
    np.testing.assert_allclose(u_hs, u_ns, atol=1e-9)  # ideal instruments: HS is NS
    gap = np.max(np.abs(u_hs - exact)) / np.max(np.abs(exact))
    if alpha == 0.0:
        assert gap < 1e-9  # the alpha method with alpha = 0 is the trapezoidal rule, exactly
    else:
        assert gap > 1e-3  # the default alpha's own period and numerical damping, not alpha = 0
