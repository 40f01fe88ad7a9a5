"""The FC-vs-DC parametric study (docs/method.md section 3, the paper's Figure 12), on a reduced grid."""

import json
import re

import numpy as np
import pytest
from click.testing import CliRunner

from hsio import study
from hsio.cli import main


@pytest.fixture(scope="module")
def rows():
    return study.fc_vs_dc(theta_values=[0.2, 1.0, 5.0])


def test_fc_and_dc_coincide(rows):
    assert len(rows) == 3 * 2 * 2 * 2
    worst = max(abs(r.er_fc_pct - r.er_dc_pct) for r in rows)
    assert worst <= 0.01


def test_error_grows_with_dt_and_theta_and_stays_in_the_papers_bounds(rows):
    by = {(r.alpha, r.zeta, r.dt, r.theta): r for r in rows}
    for alpha in (0.0, -0.3):
        for zeta in (0.0, 0.05):
            for theta in (0.2, 1.0, 5.0):
                coarse, fine = by[(alpha, zeta, 0.02, theta)], by[(alpha, zeta, 0.005, theta)]
                assert coarse.er_dc_pct > fine.er_dc_pct > 0
                assert coarse.er_dc_pct < 20.0 and fine.er_dc_pct < 5.0
            for dt in (0.02, 0.005):
                er = [by[(alpha, zeta, dt, th)].er_fc_pct for th in (0.2, 1.0, 5.0)]
                assert er[0] < er[1] < er[2]


def test_inverse_and_energy_of_the_spring():
    theta = np.array([0.2, 1.0, 5.0])
    u = np.array([-3.0, 0.7, 2.5])
    assert np.allclose(study.mp_displacement(study.mp_force(u, theta), theta), u, rtol=1e-12)
    # the energy is the integral of the force
    x = np.linspace(0, 2.5, 20001)
    R = study.mp_force(x, 5.0)
    assert study.mp_energy(2.5, 5.0) == pytest.approx(np.trapezoid(R, x), rel=1e-6)


def test_cli_json_and_plot(tmp_path):
    png = tmp_path / "fig12.png"
    result = CliRunner().invoke(main, ["study", "fc-vs-dc", "--json", "--thetas", "2", "--plot", str(png)])
    assert result.exit_code == 0, result.output
    data = json.loads(result.output)
    assert len(data) == 2 * 2 * 2 * 2
    assert set(data[0]) == {"alpha", "zeta", "dt", "theta", "er_dc_pct", "er_fc_pct"}
    assert png.stat().st_size > 10_000


@pytest.mark.parametrize("theta", [-1.0, 0.0, 1e9])
def test_a_theta_outside_the_spring_is_refused_naming_it(theta):
    from hsio.errors import ConfigError

    with pytest.raises(ConfigError, match=re.escape(f"theta = {theta:g} is out of bounds")):
        study.fc_vs_dc([1.0, theta])
