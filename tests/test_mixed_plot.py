"""modes.png: each element's mode over the run and what its switching rule reads, against the
rule's thresholds (docs/force_control.md, "Running it")."""

import numpy as np
import pytest

from hsio import plots
from hsio.api import NumericalSite, make_integrator, simulate
from hsio.ground_motion import synthetic_record
from hsio.integrators import SwitchingRule
from hsio.structures import get_structure


def _drawn(monkeypatch, tmp_path, rule):
    structure = get_structure("structure_I")
    ground = synthetic_record(duration_s=1.0, dt=structure.dt, pga_g=0.6, seed=1994)
    hs = simulate(structure, ground, NumericalSite.of(structure), integrator=make_integrator(structure, "mixed", rule=rule))
    figures = []
    monkeypatch.setattr(plots.plt, "close", figures.append)
    plots.control_modes(tmp_path / "modes.png", hs)
    (fig,) = figures
    ax = fig.axes[1]
    lines = {line.get_label(): line for line in ax.get_lines()}
    return hs, ax, lines


@pytest.mark.parametrize("on", ["stiffness", "force"])
def test_the_panel_shows_what_the_rule_reads_against_its_thresholds(monkeypatch, tmp_path, on):
    rule = (SwitchingRule.from_initial_stiffness([2.6]) if on == "stiffness"
            else SwitchingRule(np.array([20.0]), np.array([10.0]), "force"))
    hs, ax, lines = _drawn(monkeypatch, tmp_path, rule)
    up, down = ("K_f", "K_d") if on == "stiffness" else ("R_f", "R_d")
    assert lines[f"{up} (to FC)"].get_ydata()[0] == rule.upper[0]
    assert lines[f"{down} (to DC)"].get_ydata()[0] == rule.lower[0]
    shown = lines["secant stiffness" if on == "stiffness" else "|restoring force|"].get_ydata()
    read = hs.secant[:, 0] if on == "stiffness" else np.abs(hs.measured_force[:, 0])
    np.testing.assert_array_equal(shown, read)
