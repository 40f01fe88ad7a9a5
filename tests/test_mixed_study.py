"""`hsio study mixed` in its CI size: a 2 x 2 x 2 grid on short records (docs/force_control.md)."""

import json
import math

import pytest
from click.testing import CliRunner

from hsio import study_mixed as sm


@pytest.fixture(scope="module")
def rows():
    return sm.grid(duration_s=0.6)


def _get(rows, k0, du, dF, method):
    (row,) = [r for r in rows if (r.k0_kN_mm, r.resolution_mm, r.force_resolution_kN, r.method) == (k0, du, dF, method)]
    return row


def test_grid_shape(rows):
    assert len(rows) == 2 * 2 * 2 * 3
    assert all(math.isfinite(r.error_pct) and r.ns_peak_mm > 0 for r in rows)


def test_stiff_specimen_coarse_transducer_fc_and_mixed_beat_dc(rows):
    """k0 = 122.6 kN/mm with a 0.025 mm transducer: k delta_u = 3 kN of force error in DC."""
    for dF in (0.002, 0.02):
        dc = _get(rows, 122.6, 0.025, dF, "implicit_dc").error_pct
        mixed = _get(rows, 122.6, 0.025, dF, "mixed")
        assert mixed.error_pct * 2 <= dc
        assert mixed.fc_fraction > 0.5


def test_flexible_specimen_fine_transducer_mixed_stays_in_dc(rows):
    """k0 = 7.2 kN/mm with a 0.0025 mm transducer: k delta_u below c delta_F, no reason to switch."""
    for dF in (0.002, 0.02):
        dc = _get(rows, 7.2, 0.0025, dF, "implicit_dc")
        mixed = _get(rows, 7.2, 0.0025, dF, "mixed")
        assert mixed.switches == 0 and mixed.error_pct == dc.error_pct


def test_mixed_is_never_much_worse_than_the_better_of_dc_and_fc_where_it_switches(rows):
    """Where the instruments rule puts FC (k0 > K_f = c max(delta_F, tol_F) / delta_u), mixed is
    within 20 % or 0.1 percentage point of the better of DC and FC; elsewhere it is DC exactly."""
    r = sm.Recipe()
    for (case, k0, du, dF), verdict in sm.winners(rows).items():
        if k0 > r.margin * max(dF, r.tol_force) / du:
            assert verdict["mixed_ok"], (k0, du, dF)
        else:
            assert _get(rows, k0, du, dF, "mixed").error_pct == _get(rows, k0, du, dF, "implicit_dc").error_pct


def test_cli_json_and_plot(tmp_path):
    from hsio.commands.study import study

    png = tmp_path / "maps.png"
    out = CliRunner().invoke(study, ["mixed", "--json", "--stiffness", "122.6", "--resolution", "0.025",
                                     "--force-resolution", "0.01", "--duration", "0.3", "--plot", str(png)])
    assert out.exit_code == 0, out.output
    data = json.loads(out.output)
    assert {r["method"] for r in data["rows"]} == {"implicit_dc", "force_control", "mixed"}
    assert data["winners"][0]["best"] in ("force_control", "mixed")
    assert png.stat().st_size > 0
