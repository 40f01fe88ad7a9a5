"""An experimental element between two DOFs (``ref``, docs/structures.md): a storey between two
floors. Its actuator imposes the drift u[dof] - u[ref] and its force acts +R on ``dof`` and -R on
``ref`` (the element's incidence E). Checked against a closed-form reference (scipy), against the
same building whose storey is a numerical spring, by the equilibrium of the recorded forces, and
on the emulated actuator through `hsio run`."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import scipy.integrate

from hsio import api
from hsio.errors import ConfigError
from hsio.experiment import start_present
from hsio.ground_motion import GroundMotion
from hsio.integrators import ImplicitAlpha
from hsio.result import max_error_pct
from hsio.secant import SecantEstimator
from hsio.sites import NumericalSite
from hsio.structure_file import load_structure
from hsio.structures import Damping, ExperimentalElement, Spring, Structure

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
M1, M2, K1, K2, DT = 0.05, 0.04, 40.0, 25.0, 0.002
IMPLICIT = ("implicit_dc", "force_control", "mixed")


def storey_building() -> Structure:
    """Storey 1 a numerical spring to the ground, storey 2 (roof to floor1) experimental, linear k2."""
    return Structure("storey", ("floor1", "roof"), (M1, M2),
                     experimental=(ExperimentalElement("storey2", 1, {"kind": "linear", "k": K2}, ref=0),),
                     springs=(Spring(0, None, K1, "storey1"),), damping=Damping(0.03, "rayleigh"), dt=DT)


def spring_building() -> Structure:
    """The same building with storey 2 a numerical spring (storey 1 the experimental element)."""
    return Structure("spring", ("floor1", "roof"), (M1, M2),
                     experimental=(ExperimentalElement("storey1", 0, {"kind": "linear", "k": K1}),),
                     springs=(Spring(1, 0, K2, "storey2"),), damping=Damping(0.03, "rayleigh"), dt=DT)


def harmonic(duration: float = 2.0) -> GroundMotion:
    t = np.arange(0.0, duration, DT)
    return GroundMotion("harmonic", DT, 0.2 * np.sin(2 * np.pi * 2.5 * t) * (t < 1.2))


def ns(structure: Structure, ground: GroundMotion, method: str):
    if method == "alpha_os":
        return api.run_numerical(structure, ground, "alpha_os", -0.05)
    integrator = api.make_integrator(structure, method, -0.05, j_max=20, tol_displacement=1e-10, tol_force=1e-10)
    return api.simulate(structure, ground, NumericalSite.of(structure), integrator=integrator)


def test_the_storey_stiffness_joins_the_two_floors():
    s = storey_building()
    assert s.incidence.tolist() == [[-1.0, 1.0]]
    assert s.K_EI.tolist() == [[K2, -K2], [-K2, K2]]
    assert np.array_equal(s.K_init, spring_building().K_init)


@pytest.mark.parametrize("method", ("alpha_os", *IMPLICIT))
def test_ns_matches_the_building_with_a_numerical_storey_and_scipy(method):
    """Every method: the experimental storey gives the building's response with a numerical
    spring there (the alpha method's own numbers), and within 0.5 % of the exact one (scipy)."""
    ground = harmonic(1.5)
    a, b = ns(storey_building(), ground, method), ns(spring_building(), ground, method)
    peak = np.max(np.abs(b.u))
    assert peak > 10.0
    assert np.max(np.abs(a.u - b.u)) < 1e-9 * peak
    drift = a.u[:, 1] - a.u[:, 0]
    if method == "alpha_os":  # the element is driven to the predicted drift
        assert np.allclose(a.targets[:, 0], a.u_pred[:, 1] - a.u_pred[:, 0], rtol=0, atol=1e-12)
    else:  # the accepted solution's drift
        assert np.allclose(a.u_solution[1:, 0], drift[1:], rtol=0, atol=1e-9)
    s = storey_building()
    M_inv, C, K = np.linalg.inv(s.M), s.C, s.K_init
    t = a.t
    accel = ground.accel_g * 9810.0

    def rhs(tt, y):
        return np.concatenate([y[2:], -s.iota * np.interp(tt, t, accel) - M_inv @ (C @ y[2:] + K @ y[:2])])

    exact = scipy.integrate.solve_ivp(rhs, (0.0, t[-1]), np.zeros(4), t_eval=t, rtol=1e-10, atol=1e-12, max_step=DT)
    assert np.max(np.abs(a.u - exact.y[:2].T)) < 0.005 * np.max(np.abs(exact.y[:2]))


@pytest.mark.parametrize("method", ("alpha_os", *IMPLICIT))
def test_hs_on_the_emulated_actuator_follows_the_building_with_a_numerical_storey(method):
    """HS with the storey on the emulated actuator (its transducer noise and quantisation) against
    NS of the building whose storey is a numerical spring: within 0.5 % of the peak."""
    ground = harmonic(1.5)
    reference = ns(spring_building(), ground, method)
    s = storey_building()
    estimator = SecantEstimator("average", 8, 0.1) if method in ("force_control", "mixed") else None
    with api.open_site(s, "emulator://", test_rate=10.0, options={"force_limit_kN": 1000.0}, estimator=estimator) as site:
        hs = api.simulate(s, ground, site, method, -0.05)
    assert np.max(np.abs(reference.u)) > 10.0
    error, _ = max_error_pct(hs.u, reference.u)
    assert error < 0.5
    drift = hs.u[:, 1] - hs.u[:, 0]  # what the actuator measured is the drift, not the roof's displacement
    assert np.max(np.abs(hs.measured_displacement[:, 0] - drift)) < 0.05 * np.max(np.abs(drift))


@pytest.mark.parametrize("method", ("alpha_os", "implicit_dc"))
def test_the_recorded_forces_of_the_storey_are_in_equilibrium(method):
    """R per DOF less the numerical part is the element's contribution E^T F: +F at the roof,
    -F at floor 1, summing to zero at every step."""
    s = storey_building()
    r = ns(s, harmonic(), method)
    u = r.u_pred if method == "alpha_os" else r.u
    element = r.R - u @ s.K_N.T
    assert np.max(np.abs(element[:, 1])) > 100.0
    assert np.allclose(element.sum(axis=1), 0.0, rtol=0, atol=1e-9)
    F = r.measured_force[:, 0] if method == "alpha_os" else r.R_solution[:, 0]
    assert np.allclose(element[1:, 1], F[1:], rtol=0, atol=1e-9)


def test_start_present_puts_the_floor_below_in_equilibrium_with_the_storey():
    """The specimen stands at drift d with force F: floor 1 carries F on its spring (k1 u1 = F),
    the roof stands d above it."""
    s = storey_building()
    integrator = api.make_integrator(s, "alpha_os", -0.05)

    class Standing:
        def committed(self):
            return np.array([3.0]), np.array([80.0])

    out = start_present(integrator, s, np.zeros(2), Standing(), s.numerical_assembly())
    assert out.u == pytest.approx([80.0 / K1, 80.0 / K1 + 3.0], abs=1e-12)
    assert out.R == pytest.approx([0.0, 80.0], abs=1e-9)  # floor 1 at rest; the roof carries the storey force


def test_independent_mode_is_for_elements_to_the_ground():
    with pytest.raises(ConfigError, match="to the ground"):
        ImplicitAlpha(np.eye(2), np.zeros((2, 2)), None, [0, 1], [1.0, 1.0], 0.01, independent=True,
                      element_refs=[None, 0])



def test_a_ref_outside_the_structure_is_named_as_the_ref():
    with pytest.raises(ConfigError, match=r"element 'storey2': ref \(its other end\) is DOF 5, not in 0..1"):
        Structure("storey", ("floor1", "roof"), (M1, M2),
                  experimental=(ExperimentalElement("storey2", 1, {"kind": "linear", "k": K2}, ref=5),),
                  springs=(Spring(0, None, K1, "storey1"),), damping=Damping(0.03, "rayleigh"), dt=DT)


@pytest.mark.parametrize("dofs", ([2], [-1]))
def test_alpha_os_refuses_an_element_dof_outside_the_structure(dofs):
    """A DOF index past the last, or negative (which numpy would take as the last DOF), is refused."""
    from hsio.integrators.alpha_os import OperatorSplitting

    with pytest.raises(ConfigError, match=f"DOF {dofs[0]} is not in 0..1"):
        OperatorSplitting(np.eye(2), np.zeros((2, 2)), np.eye(2), DT, -0.05, dofs, [1.0])


BUILDING = """
[structure]
dt = 0.005
[[dof]]
name = "floor1"
mass = 0.05
[[dof]]
name = "roof"
mass = 0.04
[[spring]]
dof = "floor1"
k = 40.0
[[experimental]]
name = "storey2"
dof = "roof"
{extra}
model = {{ kind = "linear", k = 25.0 }}
"""


@pytest.mark.parametrize("extra, message", [
    ('ref = "floor2"', "unknown DOF 'floor2'"),
    ('ref = "roof"', "the element joins DOF 'roof' to itself"),
    ('ref = "floor1"\nsetup = { kind = "none" }', "an element between two DOFs .* gives setup"),
    ('ref = "floor1"\nactuators = ["a"]', "an element between two DOFs .* gives actuators"),
    ('ref = 1', "must be a non-empty string"),
])
def test_a_bad_ref_is_refused_naming_the_key(tmp_path, extra, message):
    path = tmp_path / "frame.toml"
    path.write_text(BUILDING.format(extra=extra))
    with pytest.raises(ConfigError, match=r"frame\.toml: experimental\[0\]\.ref: " + message):
        load_structure(path)


def test_ref_is_read_from_the_file(tmp_path):
    path = tmp_path / "frame.toml"
    path.write_text(BUILDING.format(extra='ref = "floor1"'))
    s = load_structure(path)
    assert s.experimental[0].ref == 0 and s.experimental_refs == [0]
    path.write_text(BUILDING.format(extra='ref = "ground"'))  # the default, spelt out
    assert load_structure(path).experimental[0].ref is None


def test_ref_is_refused_for_an_element_with_several_basic_dofs():
    with pytest.raises(ConfigError, match="ref"):
        ExperimentalElement("column", 0, {"kind": "matrix", "K": ((1.0, 0.0), (0.0, 1.0))}, dofs=(0, 1), ref=2)


def test_the_two_storey_example_runs_on_the_emulated_actuator(tmp_path):
    """`hsio check` and `hsio run` on examples/run_two_storey.toml: the actuator follows the storey
    drift (the dry run checks the drift against the stroke, not the roof's displacement) and HS
    follows NS."""
    config = tmp_path / "run.toml"
    config.write_text((EXAMPLES / "run_two_storey.toml").read_text().replace(
        'file = "two_storey.toml"', f"file = {json.dumps(str(EXAMPLES / 'two_storey.toml'))}").replace(
        "synthetic_duration_s = 5.0", "synthetic_duration_s = 2.0") + "\n[output]\nplots = false\n")

    def hsio(*args):
        proc = subprocess.run([sys.executable, "-m", "hsio.cli", *args, "--json"], capture_output=True, text=True,
                              timeout=300)
        assert "Traceback" not in proc.stderr, proc.stderr
        assert proc.returncode == 0, proc.stderr
        return json.loads(proc.stdout)

    check = hsio("check", str(config))
    summary = hsio("run", str(config), "--out", str(tmp_path / "o"))
    assert summary["structure"] == "two_storey" and summary["steps"] == 400 and not summary["stopped"]
    assert summary["max_error_pct"] < 2.0, summary["max_error_pct_per_dof"]
    from hsio.recording import Run

    steps = Run(tmp_path / "o" / "run.sqlite").steps
    drift = steps["u_pred_roof"] - steps["u_pred_floor1"]
    assert np.max(np.abs(drift)) > 10.0  # the storey softens past its drift of 10 mm
    assert np.max(np.abs(drift)) < 0.8 * np.max(np.abs(steps["u_roof"]))  # the drift is not the roof's motion
    assert np.allclose(steps["target_act2"], drift, rtol=0, atol=1e-9)
    assert check["peak_displacement_mm"][0] == pytest.approx(np.max(np.abs(drift)), rel=0.05)


def test_the_control_modes_plot_shows_the_drift_of_the_storey(monkeypatch, tmp_path):
    """modes.png of an implicit run: the storey's panel draws its drift u_roof - u_floor1 (what
    its actuator was commanded), not the roof's displacement."""
    from hsio import plots

    s = storey_building()
    hs = ns(s, harmonic(0.6), "mixed")
    figures = []
    monkeypatch.setattr(plots.plt, "close", figures.append)
    plots.control_modes(tmp_path / "modes.png", hs, s.incidence)
    (fig,) = figures
    (line,) = [ln for ln in fig.axes[0].get_lines() if ln.get_label() == "drift"]
    drift = hs.u[:, 1] - hs.u[:, 0]
    assert np.max(np.abs(hs.u[:, 1] - drift)) > 1.0
    np.testing.assert_allclose(line.get_ydata(), drift, rtol=0, atol=1e-12)
    assert "storey2: roof - floor1" in fig.axes[0].get_ylabel()


ROTATION = """
[structure]
dt = 0.005
[[dof]]
name = "top_x"
mass = 0.05
[[dof]]
name = "top_rot"
mass = 50.0
iota = 0.0
[[dof]]
name = "roof"
mass = 0.04
[[experimental]]
name = "column"
dofs = ["top_x", "top_rot"]
actuators = ["lower", "upper"]
setup = { kind = "two_actuators", length_mm = 1500.0, spacing_mm = 500.0 }
model = { kind = "cantilever", EI = 2.0e9, L = 2000.0 }
[[experimental]]
name = "brace"
dof = "roof"
ref = "REF"
model = { kind = "linear", k = 10.0 }
"""


def test_a_ref_at_a_rotation_is_refused_naming_the_key(tmp_path):
    """A drift u[dof] - u[ref] between mm and rad means nothing: a setup's theta is no end of an
    element between two DOFs; its translation is."""
    path = tmp_path / "frame.toml"
    path.write_text(ROTATION.replace("REF", "top_rot"))
    with pytest.raises(ConfigError, match=r"frame\.toml: experimental\[1\]\.ref: DOF 'top_rot' is a rotation"):
        load_structure(path)
    path.write_text(ROTATION.replace("REF", "top_x"))
    assert load_structure(path).experimental_refs == [None, None, 0]
