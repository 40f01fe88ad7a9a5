"""Viscous damping of the structures: the modal damping ratios that the damping kinds give
(mass, stiffness, Rayleigh on modes 1-2; E&M 2007, Tables I-III), and the natural frequencies,
against eigenvectors computed here from M and K."""

import numpy as np
import pytest
import scipy.linalg

from hsio.structures import Damping, ExperimentalElement, Spring, Structure, get_structure, sdof


def three_storey(kind: str, zeta: float) -> tuple[Structure, np.ndarray, np.ndarray]:
    """A 3-storey shear building: storey 1 experimental, storeys 2 and 3 numerical springs."""
    m = (0.02, 0.015, 0.01)
    k = (12.0, 8.0, 5.0)
    s = Structure(
        "three storeys", ("1", "2", "3"), m,
        (ExperimentalElement("storey 1", 0, {"kind": "linear", "k": k[0]}),),
        springs=(Spring(0, 1, k[1]), Spring(1, 2, k[2])), damping=Damping(zeta, kind), dt=0.005)
    M = np.diag(m)
    K = np.array([[k[0] + k[1], -k[1], 0.0], [-k[1], k[1] + k[2], -k[2]], [0.0, -k[2], k[2]]])
    return s, M, K


def modal_damping(C, M, K):
    w2, phi = scipy.linalg.eigh(K, M)
    w = np.sqrt(w2)
    ratios = np.array([phi[:, i] @ C @ phi[:, i] / (2 * w[i] * phi[:, i] @ M @ phi[:, i]) for i in range(len(w))])
    return w, ratios


def test_rayleigh_damping_gives_zeta_in_modes_1_and_2_and_the_formula_in_mode_3():
    zeta = 0.05
    s, M, K = three_storey("rayleigh", zeta)
    C = s.C
    assert np.allclose(C, C.T, rtol=0, atol=1e-15)
    w, ratios = modal_damping(C, M, K)
    assert ratios[0] == pytest.approx(zeta, rel=1e-10)
    assert ratios[1] == pytest.approx(zeta, rel=1e-10)
    a0 = 2 * zeta * w[0] * w[1] / (w[0] + w[1])
    a1 = 2 * zeta / (w[0] + w[1])
    assert ratios[2] == pytest.approx(a0 / (2 * w[2]) + a1 * w[2] / 2, rel=1e-10)
    assert ratios[2] > zeta  # above the second mode Rayleigh damping grows
    assert np.allclose(C, a0 * M + a1 * K, rtol=1e-12, atol=0)


def test_mass_and_stiffness_proportional_damping_ratios():
    zeta = 0.04
    s, M, K = three_storey("mass", zeta)
    w, ratios = modal_damping(s.C, M, K)
    assert np.allclose(ratios, zeta * w[0] / w, rtol=1e-10)
    s, M, K = three_storey("stiffness", zeta)
    w, ratios = modal_damping(s.C, M, K)
    assert np.allclose(ratios, zeta * w / w[0], rtol=1e-10)


def test_single_dof_mass_and_stiffness_damping_give_zeta():
    m, k, zeta = 0.011, 2.6, 0.05
    for kind in ("mass", "stiffness"):
        s = Structure("one", ("x",), (m,), (ExperimentalElement("x", 0, {"kind": "linear", "k": k}),),
                      damping=Damping(zeta, kind))
        assert s.C[0, 0] == pytest.approx(2 * zeta * np.sqrt(k * m), rel=1e-12), kind
    assert sdof(m=1.0, k=4 * np.pi**2, zeta=0.02).C[0, 0] == pytest.approx(2 * 0.02 * 2 * np.pi, rel=1e-12)


def test_natural_frequencies_of_the_three_storey_building():
    s, M, K = three_storey("rayleigh", 0.05)
    w2 = scipy.linalg.eigh(K, M, eigvals_only=True)
    assert np.allclose(s.natural_frequencies_hz(), np.sqrt(w2) / (2 * np.pi), rtol=1e-12)


def test_validation_structure_modes_and_damping():
    """Table I: C1 0.613 kN/mm and 0.0017, C2 0.536 kN/mm and 0.0011 (initial), coupled by a stiff
    numerical spring; zeta = 5 % mass-proportional; T1 = 0.31 s."""
    s = get_structure("validation")
    M = np.diag([0.0017, 0.0011])
    f = s.natural_frequencies_hz()
    assert 1 / f[0] == pytest.approx(0.31, abs=0.01)
    # a stiff coupling: the first mode is the two masses moving together on both columns
    assert f[0] == pytest.approx(np.sqrt((0.613 + 0.536) / 0.0028) / (2 * np.pi), rel=0.01)
    assert np.allclose(s.C, 2 * 0.05 * 2 * np.pi * f[0] * M, rtol=1e-12)


def test_damping_on_modes_the_structure_lacks_is_refused_when_it_is_built():
    """A one-DOF structure built in code keeps the default Rayleigh damping (modes 1 and 2) only
    to be refused at once, naming the fix, not later when a run asks for C."""
    from hsio.errors import ConfigError

    wall = ExperimentalElement(name="w", dof=0, specimen={"kind": "linear", "k": 1.0})
    with pytest.raises(ConfigError, match=r"damping 'rayleigh' on modes \[1, 2\], but the structure has 1 mode\(s\) "
                                          r"\(Rayleigh damping takes two modes: on one DOF give Damping\(zeta, kind='mass'\)"):
        Structure("one", ("x",), (0.01,), (wall,))
    with pytest.raises(ConfigError, match=r"damping 'mass' on modes \[3\], but the structure has 2 mode"):
        Structure("two", ("x", "y"), (0.01, 0.01), (wall,), damping=Damping(0.05, "mass", (3,)))
    with pytest.raises(ConfigError, match="damping kind must be one of"):
        Structure("one", ("x",), (0.01,), (wall,), damping=Damping(0.05, "viscous"))
    assert Structure("one", ("x",), (0.01,), (wall,), damping=Damping(0.05, "mass")).n_dof == 1


def two_equal_storeys(damping: Damping) -> Structure:
    """Two uncoupled identical specimens: two modes at one frequency, w = sqrt(k / m) = 10 rad/s."""
    return Structure("twins", ("a", "b"), (0.01, 0.01),
                     tuple(ExperimentalElement(d, k, {"kind": "linear", "k": 1.0}) for k, d in enumerate("ab")),
                     damping=damping, dt=0.01)


def test_rayleigh_on_two_modes_of_one_frequency():
    """One ratio on two modes at one frequency w gives a0 = zeta w, a1 = zeta / w and that ratio
    to both; two different ratios cannot be met there and are refused naming the key."""
    from hsio.errors import ConfigError

    s = two_equal_storeys(Damping(0.05, "rayleigh"))
    np.testing.assert_allclose(s.C, 0.05 * 10.0 * s.M + 0.05 / 10.0 * s.K_init, rtol=1e-12)
    np.testing.assert_allclose(s.damping_ratios(), [0.05, 0.05], rtol=1e-12)
    with pytest.raises(ConfigError, match=r"damping.modes: rayleigh damping cannot give modes 1 and 2 two ratios "
                                          r"\(2 % and 5 %\): both are at 1.59155 Hz"):
        two_equal_storeys(Damping((0.02, 0.05), "rayleigh"))
    with pytest.raises(ConfigError, match=r"damping.zeta: modal damping cannot give modes 1 and 2 two ratios"):
        two_equal_storeys(Damping((0.02, 0.05), "modal"))  # which twin would be 'mode 1' is the DOFs' order
    np.testing.assert_allclose(two_equal_storeys(Damping((0.05, 0.05), "modal")).damping_ratios(), [0.05, 0.05])
