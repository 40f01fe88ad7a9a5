"""The Python API as a notebook uses it, with structures built in code: closed forms for a linear
SDOF under harmonic base acceleration, and misuse refused with an HsioError that names it."""

import numpy as np
import pytest

import hsio
from hsio.integrators import SwitchingRule
from hsio.structures import Damping, ExperimentalElement, Spring, Structure

G_MM_S2 = 9806.65


def sdof(k=0.8, m=0.0005, zeta=0.03, dt=0.005):
    return Structure("sdof", ("x",), (m,), (ExperimentalElement("E", 0, {"kind": "linear", "k": k}),),
                     damping=Damping(zeta, "mass"), dt=dt)


def harmonic(structure, f_hz, amp_g, duration_s):
    t = np.arange(0.0, duration_s + 1e-9, structure.dt)
    return hsio.GroundMotion(f"sine {f_hz} Hz", structure.dt, amp_g * np.sin(2 * np.pi * f_hz * t))


def steady_state(result, f_hz, last_s):
    """Amplitude and phase of u = A sin(w t + phi) fitted over the last ``last_s`` of the run."""
    w = 2 * np.pi * f_hz
    sel = result.t > result.t[-1] - last_s
    basis = np.c_[np.sin(w * result.t[sel]), np.cos(w * result.t[sel])]
    (a, b), *_ = np.linalg.lstsq(basis, result.u[sel, 0], rcond=None)
    return np.hypot(a, b), np.arctan2(b, a)


def closed_form(structure, f_hz, amp_g):
    """u = -A g / (w_n^2 D) sin(w t - theta): amplitude and phase (as A sin(w t + phi))."""
    k = structure.experimental[0].K_EI
    m = structure.masses[0]
    zeta = structure.damping.zeta
    wn = np.sqrt(k / m)
    r = 2 * np.pi * f_hz / wn
    amplitude = amp_g * G_MM_S2 / (wn**2 * np.hypot(1 - r**2, 2 * zeta * r))
    theta = np.arctan2(2 * zeta * r, 1 - r**2)
    return amplitude, np.angle(np.exp(1j * (np.pi - theta)))


@pytest.mark.filterwarnings("ignore:mixed. the site has no secant estimator")  # a linear specimen
@pytest.mark.parametrize("method", ["alpha_os", "implicit_dc", "mixed"])
def test_linear_sdof_reaches_the_closed_form_steady_state(method):
    structure = sdof()
    ground = harmonic(structure, 3.0, 0.05, 6.0)
    amplitude, phase = closed_form(structure, 3.0, 0.05)
    ns = hsio.run_numerical(structure, ground)
    a_ns, p_ns = steady_state(ns, 3.0, 2.0)
    assert a_ns == pytest.approx(amplitude, rel=0.005) and p_ns == pytest.approx(phase, abs=0.005)
    with hsio.open_site(structure, "emulator://", test_rate=7.5, options={"noise_mm": 0.0}) as site:
        hs = hsio.simulate(structure, ground, site, method=method)
    a_hs, p_hs = steady_state(hs, 3.0, 2.0)
    assert a_hs == pytest.approx(amplitude, rel=0.03) and p_hs == pytest.approx(phase, abs=0.02)


def test_open_site_refuses_test_settings_out_of_range_before_opening():
    structure = sdof()
    for kwargs, what in (({"test_rate": 0}, "test_rate"), ({"test_rate": float("nan")}, "test_rate"),
                         ({"hold_fraction": 1.5}, "hold_fraction"), ({"n_avg": 0}, "n_avg"),
                         ({"n_avg": 2.5}, "n_avg"), ({"n_avg": 10**9}, "n_avg")):
        with pytest.raises(hsio.ConfigError, match=what):
            hsio.open_site(structure, "emulator://", **kwargs)


def test_a_structure_without_experimental_elements_is_refused_by_a_hybrid_call():
    numerical = Structure("springs only", ("x",), (0.0005,), (), springs=(Spring(0, None, 0.8),),
                          damping=Damping(0.02, "mass"), dt=0.005)
    with pytest.raises(hsio.ConfigError, match="no experimental elements"):
        hsio.open_site(numerical, "emulator://")
    structure = sdof()
    ground = hsio.synthetic_record(duration_s=0.2, dt=structure.dt, seed=1)
    with hsio.open_site(structure, "emulator://") as site:
        with pytest.raises(hsio.ConfigError, match="no experimental elements"):
            hsio.simulate(numerical, ground, site)


def test_simulate_on_a_closed_site_says_the_site_is_closed():
    structure = sdof()
    ground = hsio.synthetic_record(duration_s=0.2, dt=structure.dt, seed=1)
    with hsio.open_site(structure, "emulator://") as site:
        pass
    with pytest.raises(hsio.ConfigError, match="closed"):
        hsio.simulate(structure, ground, site)


def test_simulate_refuses_a_ground_motion_that_is_not_one_component():
    structure = sdof()
    with pytest.raises(hsio.ConfigError, match="GroundMotion"):
        hsio.run_numerical(structure, np.zeros(100))
    with pytest.raises(hsio.errors.RecordError, match="1-D"):  # refused where it is built
        hsio.GroundMotion("two components", structure.dt, np.full((100, 2), 0.01))


def test_integrator_arguments_of_the_wrong_kind_or_size_are_refused():
    structure = sdof()
    ground = hsio.synthetic_record(duration_s=0.2, dt=structure.dt, seed=1)
    with pytest.raises(hsio.ConfigError, match="alpha"):
        hsio.run_numerical(structure, ground, alpha="x")
    with pytest.raises(hsio.ConfigError, match="2 threshold"):
        hsio.simulate(structure, ground, hsio.NumericalSite.of(structure), method="mixed",
                      rule=SwitchingRule([1.0, 2.0], [0.5, 0.6]))


def test_a_specimen_parameter_that_is_not_a_finite_number_is_named():
    for k in (float("nan"), float("inf"), "0.8"):
        with pytest.raises(hsio.ConfigError, match="specimen 'linear': k must be a finite number"):
            sdof(k=k).experimental[0].model()


def test_max_error_pct_refuses_histories_of_different_dofs():
    with pytest.raises(hsio.HsioError, match="same DOF"):
        hsio.max_error_pct(np.zeros((10, 2)), np.ones((5, 1)))
    worst, per_dof = hsio.max_error_pct(np.ones((10, 2)), np.full((5, 2), 2.0))
    assert worst == pytest.approx(50.0) and per_dof == pytest.approx([50.0, 50.0])


# -- the monitor on records other than hsio run's ----------------------------------------------------
TWO_STOREY = """
[structure]
name = "two_storey"
dt = 0.005
[[dof]]
name = "f1"
mass = 0.002
[[dof]]
name = "f2"
mass = 0.0015
[damping]
kind = "mass"
zeta = 0.03
[[experimental]]
name = "brace"
dof = "f2"
model = { kind = "linear", k = 1.2 }
[[spring]]
name = "storey1"
dof = "f1"
k = 3.0
"""


def test_the_monitor_shows_a_served_element_whose_dof_has_another_name(tmp_path):
    """`hsio serve opensees` records the served element's channel as its DOF: the element 'brace'
    at DOF 'f2' of its structure file is recorded as DOF 'brace'."""
    from bokeh.document import Document

    from hsio.monitor.feed import RecordFeed
    from hsio.monitor.operator import Operator
    from hsio.monitor.page import MonitorPage
    from hsio.recording import Recorder

    (tmp_path / "two.toml").write_text(TWO_STOREY)
    meta = {"config": {"structure": {"name": "validation", "file": str(tmp_path / "two.toml")}},
            "structure": "two_storey", "source": "opensees genericClient"}
    rec = Recorder(tmp_path / "run.sqlite", ["brace"], ["brace"], meta)
    for k in range(1, 11):
        u = [0.1 * k]
        rec.write_step(k, 0.005 * k, u, [0.0], [0.0], u, [1.2 * u[0]], ["displacement"], u, u, u, [1.2 * u[0]])
    rec.write_summary({"steps": 10, "end": "DIE received"})
    rec.close()
    feed = RecordFeed(tmp_path)
    page = MonitorPage(Document(), feed, Operator(tmp_path))
    assert page.built and feed.n == 10 and feed.channel_dof == {"brace": "brace"}
    assert "brace stroke" in page.margins.data["label"]
    feed.close()
