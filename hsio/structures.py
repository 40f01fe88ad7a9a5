"""Structures: mass, damping, numerical springs and experimental elements, per DOF.

A :class:`Structure` holds what the integrator needs (M, C, the implicit stiffness K_I, the
influence vector) and what the experiment needs (which DOF are experimental, and the specimen
model that stands behind each in emulation and in the purely numerical simulation).

The ready-made structures are the paper's (METHOD.md section 6, Tables I-III).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from hsio.errors import ConfigError
from hsio.specimens import Specimen, make_specimen


@dataclass(frozen=True)
class ExperimentalElement:
    """A physical element at one DOF, loaded by one actuator.

    ``specimen`` describes it (for the emulator and for NS); K^EI is its initial stiffness.
    """

    name: str
    dof: int
    specimen: dict

    def model(self) -> Specimen:
        return make_specimen(self.specimen)

    @property
    def K_EI(self) -> float:
        return self.model().initial_stiffness


@dataclass(frozen=True)
class Spring:
    """A numerical linear spring between DOF i and j (j = None: to the ground), k in kN/mm."""

    i: int
    j: int | None
    k: float


@dataclass(frozen=True)
class NumericalElement:
    """A numerical (possibly nonlinear) element at one DOF, to the ground."""

    name: str
    dof: int
    specimen: dict


@dataclass(frozen=True)
class Damping:
    """Viscous damping: ratio zeta, proportional to mass, stiffness or both (Rayleigh, modes 1-2)."""

    zeta: float = 0.05
    kind: str = "rayleigh"

    def matrix(self, M: np.ndarray, K: np.ndarray) -> np.ndarray:
        omega = np.sqrt(np.sort(scipy.linalg.eigh(K, M, eigvals_only=True)))
        w1 = omega[0]
        if self.kind == "mass":
            return 2 * self.zeta * w1 * M
        if self.kind == "stiffness":
            return 2 * self.zeta / w1 * K
        if self.kind == "rayleigh":
            if omega.size == 1:
                return 2 * self.zeta * w1 * M
            w2 = omega[1]
            a0 = 2 * self.zeta * w1 * w2 / (w1 + w2)
            a1 = 2 * self.zeta / (w1 + w2)
            return a0 * M + a1 * K
        raise ConfigError(f"damping kind must be 'mass', 'stiffness' or 'rayleigh', got {self.kind!r}")


@dataclass(frozen=True)
class Structure:
    """A structure for hybrid simulation, in kN, mm, s (mass in kN s^2/mm)."""

    name: str
    dof_names: tuple[str, ...]
    masses: tuple[float, ...]
    experimental: tuple[ExperimentalElement, ...]
    springs: tuple[Spring, ...] = ()
    numerical: tuple[NumericalElement, ...] = ()
    damping: Damping = field(default_factory=Damping)
    dt: float = 0.01
    description: str = ""

    def __post_init__(self):
        n = len(self.dof_names)
        if n == 0 or len(self.masses) != n:
            raise ConfigError(f"structure {self.name!r}: {len(self.masses)} masses for {n} DOF")
        if any(not m > 0 for m in self.masses):
            raise ConfigError(f"structure {self.name!r}: every mass must be positive, got {self.masses}")
        for element in (*self.experimental, *self.numerical):
            if not 0 <= element.dof < n:
                raise ConfigError(f"structure {self.name!r}: element {element.name!r} is at DOF {element.dof}, not in 0..{n - 1}")
        for s in self.springs:
            if not 0 <= s.i < n or (s.j is not None and not 0 <= s.j < n):
                raise ConfigError(f"structure {self.name!r}: spring {s} joins a DOF not in 0..{n - 1}")
        dofs = [e.dof for e in self.experimental]
        if len(set(dofs)) != len(dofs):
            raise ConfigError(f"structure {self.name!r}: two experimental elements share a DOF")
        if not self.dt > 0:
            raise ConfigError(f"structure {self.name!r}: dt must be positive")

    @property
    def n_dof(self) -> int:
        return len(self.dof_names)

    @property
    def M(self) -> np.ndarray:
        return np.diag(np.asarray(self.masses, dtype=float))

    @property
    def iota(self) -> np.ndarray:
        """Influence vector of the ground acceleration (every DOF horizontal, same direction)."""
        return np.ones(self.n_dof)

    @property
    def K_N(self) -> np.ndarray:
        """Stiffness matrix of the numerical linear springs."""
        K = np.zeros((self.n_dof, self.n_dof))
        for s in self.springs:
            K[s.i, s.i] += s.k
            if s.j is not None:
                K[s.j, s.j] += s.k
                K[s.i, s.j] -= s.k
                K[s.j, s.i] -= s.k
        return K

    @property
    def K_EI(self) -> np.ndarray:
        """Initial stiffness of the experimental elements, K^EI (diagonal)."""
        K = np.zeros((self.n_dof, self.n_dof))
        for e in self.experimental:
            K[e.dof, e.dof] += e.K_EI
        return K

    @property
    def K_num_init(self) -> np.ndarray:
        """Initial stiffness of the numerical nonlinear elements."""
        K = np.zeros((self.n_dof, self.n_dof))
        for e in self.numerical:
            K[e.dof, e.dof] += make_specimen(e.specimen).initial_stiffness
        return K

    @property
    def K_init(self) -> np.ndarray:
        """Initial stiffness of the whole structure: the implicit stiffness K_I of alpha-OS."""
        return self.K_EI + self.K_N + self.K_num_init

    @property
    def C(self) -> np.ndarray:
        return self.damping.matrix(self.M, self.K_init)

    def natural_frequencies_hz(self) -> np.ndarray:
        w2 = scipy.linalg.eigh(self.K_init, self.M, eigvals_only=True)
        return np.sqrt(np.sort(w2)) / (2 * np.pi)

    @property
    def experimental_dofs(self) -> list[int]:
        return [e.dof for e in self.experimental]

    def numerical_assembly(self) -> "NumericalAssembly":
        """The numerical part of the restoring force, R^N (fresh models in the virgin state)."""
        return NumericalAssembly(self)


class NumericalAssembly:
    """R^N(u): the numerical springs and elements of a structure, with trial and commit.

    ``K_linear`` is the stiffness of the linear part, ``K_initial`` that of every numerical
    element from the virgin state; ``is_linear`` says whether R^N = K_linear u exactly.
    """

    def __init__(self, structure: Structure):
        self.structure = structure
        self.models = [make_specimen(e.specimen) for e in structure.numerical]
        self.K_linear = structure.K_N.copy()
        self.K_initial = structure.K_N + structure.K_num_init
        self.is_linear = all(m.kind == "linear" for m in self.models)
        if self.is_linear:
            self.K_linear = self.K_initial.copy()

    def trial(self, u: np.ndarray, dt: float = 0.0) -> np.ndarray:
        """R^N at ``u`` from the committed state (committed state unchanged)."""
        u = np.asarray(u, dtype=float)
        R = self.structure.K_N @ u
        for element, model in zip(self.structure.numerical, self.models):
            R[element.dof] += model.trial(float(u[element.dof]), dt)
        return R

    def commit(self) -> None:
        for model in self.models:
            model.commit()


def validation() -> Structure:
    """The validation structure (Table I): two steel cantilevers coupled by a stiff numerical spring.

    C1 linear, k = 0.613 kN/mm, m = 0.0017; C2 bilinear stiffening when a gap closes, 0.536 then
    2.011 kN/mm, m = 0.0011; zeta = 5 %, dt = 0.01 s, T1 = 0.31 s. The paper gives neither the
    gap nor the coupling stiffness: hsio takes a 10 mm gap and a 50 kN/mm spring.
    """
    return Structure(
        name="validation",
        dof_names=("C1", "C2"),
        masses=(0.0017, 0.0011),
        experimental=(
            ExperimentalElement("C1", 0, {"kind": "linear", "k": 0.613}),
            ExperimentalElement("C2", 1, {"kind": "bilinear_gap", "k1": 0.536, "k2": 2.011, "gap": 10.0}),
        ),
        springs=(Spring(0, 1, 50.0),),
        damping=Damping(0.05, "mass"),
        dt=0.01,
        description="Table I: two cantilevers (C1 linear, C2 stiffening gap) coupled by a stiff numerical spring",
    )


def structure_I() -> Structure:
    """Test structure I (Table II): first storey of a two-storey wood house, SDOF.

    m = 0.011 kN s^2/mm, k = 2.6 kN/mm (f = 2.44 Hz), zeta = 5 % mass-proportional, dt = 0.005 s.
    The wall is the pinched wood model, sized for about +/-40 kN at +/-100 mm.
    """
    return Structure(
        name="structure_I",
        dof_names=("wall",),
        masses=(0.011,),
        experimental=(
            ExperimentalElement("wall", 0, {"kind": "pinched_wood", "k0": 2.6, "F0": 30.0, "r1": 0.05, "r3": 1.5, "r4": 0.02, "r_pinch": 0.15}),
        ),
        damping=Damping(0.05, "mass"),
        dt=0.005,
        description="Table II: wood shear wall (pinched: flexible loading, stiff unloading)",
    )


def structure_II() -> Structure:
    """Test structure II (Table III): bare (BF) and infilled (IF) RC frames linked by a slab spring.

    BF and IF are physical; a third frame mirrors BF numerically, linked to IF by a second slab
    spring. m_BF = 0.012, m_IF = 0.019; k_BF = 7.2, k_IF = 122.6, k_s = 289.0 kN/mm;
    zeta = 6.2 %, dt = 0.005 s. (With this layout the first mode is 8.8 Hz; the paper reports a
    measured 7.46 Hz.)
    """
    return Structure(
        name="structure_II",
        dof_names=("BF", "IF", "BF_mirror"),
        masses=(0.012, 0.019, 0.012),
        experimental=(
            ExperimentalElement("BF", 0, {"kind": "linear", "k": 7.2}),
            ExperimentalElement("IF", 1, {"kind": "linear", "k": 122.6}),
        ),
        springs=(Spring(0, 1, 289.0), Spring(1, 2, 289.0)),
        numerical=(NumericalElement("BF_mirror", 2, {"kind": "linear", "k": 7.2}),),
        damping=Damping(0.062, "mass"),
        dt=0.005,
        description="Table III: bare and infilled RC frames, a numerical mirror frame, slab springs",
    )


def sdof(m: float = 1.0, k: float = 4 * np.pi**2, zeta: float = 0.0, dt: float = 0.01, specimen: dict | None = None) -> Structure:
    """A single-DOF structure with one experimental element (linear unless ``specimen`` says)."""
    return Structure(
        name="sdof",
        dof_names=("x",),
        masses=(m,),
        experimental=(ExperimentalElement("x", 0, specimen or {"kind": "linear", "k": k}),),
        damping=Damping(zeta, "mass"),
        dt=dt,
    )


STRUCTURES = {"validation": validation, "structure_I": structure_I, "structure_II": structure_II}


def get_structure(name: str) -> Structure:
    try:
        return STRUCTURES[name]()
    except KeyError:
        raise ConfigError(f"unknown structure {name!r}; known: {', '.join(STRUCTURES)}") from None
