"""[integrator] keys that the configured method would not read are refused naming the key and why,
at a value other than their default (docs/config.md); where the method reads them they are taken."""

import pytest

from hsio.config import from_dict
from hsio.errors import ConfigError


@pytest.mark.parametrize("integrator, says", [
    ({"j_max": 5}, "j_max = 5 is not read by method = 'alpha_os'"),
    ({"tol_displacement_mm": 0.001}, "tol_displacement_mm = 0.001 is not read by method = 'alpha_os'"),
    ({"tol_force_kN": 0.001}, "tol_force_kN = 0.001 is not read by method = 'alpha_os'"),
    ({"secant": "raw"}, "secant = 'raw' is not read by method = 'alpha_os'"),
    ({"secant_n_avg": 8}, "secant_n_avg = 8 is not read by method = 'alpha_os'"),
    ({"secant_min_increment_mm": 0.05}, "secant_min_increment_mm = 0.05 is not read by method = 'alpha_os'"),
    ({"method": "implicit_dc", "fc_blend": 0.5}, "fc_blend is not read by method = 'implicit_dc'"),
    ({"method": "force_control", "anchor_dc": False}, "anchor_dc = False is not read by method = 'force_control'"),
    ({"method": "mixed", "secant": "least_squares", "secant_n_avg": 8},
     "secant_n_avg is read by secant = 'average' only"),
])
def test_a_key_the_method_does_not_read_is_refused(integrator, says):
    with pytest.raises(ConfigError, match=__import__("re").escape(says)):
        from_dict({"integrator": integrator}, "c.toml")


@pytest.mark.parametrize("integrator", [
    {"method": "implicit_dc", "tol_displacement_mm": 0.001, "secant": "raw", "j_max": 5},
    {"method": "force_control", "tol_force_kN": 0.001, "fc_blend": 0.5, "secant_n_avg": 8},
    {"method": "implicit_dc", "fc_blend": 0.5, "blend_dc": True, "anchor_dc": False},
    {"method": "mixed", "K_f": 3.0, "tol_displacement_mm": 0.001, "tol_force_kN": 0.001, "anchor_dc": False},
    # both tolerances with any implicit method: each element's iteration reads the one of its mode
    {"method": "implicit_dc", "tol_displacement_mm": 0.001, "tol_force_kN": 0.001},
    {"method": "force_control", "tol_displacement_mm": 0.001, "tol_force_kN": 0.001},
    {"method": "alpha_os", "j_max": 3, "anchor_dc": False},  # at its default; alpha-OS anchors nothing (documented)
])
def test_keys_the_method_reads_are_taken(integrator):
    assert from_dict({"integrator": integrator}, "c.toml")["integrator"]["method"] == integrator["method"]
