"""Structures: mass, damping, numerical springs and elements, experimental elements, per DOF.

A :class:`Structure` holds what the integrator needs (M, C, the implicit stiffness K_I, the
influence vector iota) and what the experiment needs (which DOF are experimental, the actuator
behind each, and the specimen model that stands for it in emulation and in the purely numerical
simulation, NS).

Structures are data: a structure file (TOML, docs/structures.md) read by
:func:`hsio.structure_file.load_structure`. The paper's three (docs/method.md section 6;
E&M 2007, Tables I-III) ship with hsio as ``validation``, ``structure_I`` and ``structure_II``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from hsio.errors import ConfigError
from hsio.specimens import Specimen, make_specimen


def _checker(what: str):
    """The structure-file loader's value checks, with errors that name ``what`` (a structure or
    an element built in code) and the argument."""
    from hsio.structure_file import _Reader

    return _Reader(what, what)


def _index(what: str, where: str, value) -> int:
    """A DOF index: a whole number (not a bool)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise ConfigError(f"{what}: {where}: must be a DOF index (a whole number from 0), got {value!r}")
    return int(value)


def _check_specimen(what: str, spec) -> None:
    """A specimen table that builds a model of positive, finite initial stiffness."""
    try:
        model = make_specimen(spec)
        k = float(model.initial_stiffness)
    except ConfigError as exc:
        raise ConfigError(f"{what}: specimen: {exc}") from None
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{what}: specimen {spec!r}: {exc}") from None
    if not (math.isfinite(k) and k > 0):
        raise ConfigError(f"{what}: specimen {spec!r}: initial stiffness must be positive, got {k!r}")


def _elements(what: str, where: str, value, kind: type) -> tuple:
    """A tuple of ``kind`` (a list is taken as a tuple; one element alone is refused)."""
    if isinstance(value, list):
        value = tuple(value)
    if not isinstance(value, tuple) or any(not isinstance(e, kind) for e in value):
        raise ConfigError(f"{what}: {where}: must be a tuple of {kind.__name__}, got {value!r}")
    return value


@dataclass(frozen=True)
class ExperimentalElement:
    """A physical element at one or more DOFs, loaded by one or more actuators.

    ``specimen`` describes it (for the emulator and for NS). K^EI is its initial stiffness: the
    declared ``K_EI_declared`` when the structure states one (the integrator then uses it even if
    the specimen model's differs), else the specimen model's. ``actuator`` names the actuator
    that drives it (default: the element's name).

    An element with ``dofs`` (its basic DOFs, structure DOF indices), ``actuators`` and a
    ``setup`` table is loaded through an experimental setup (docs/setups.md): its specimen is a
    multi-DOF model (q = K d) and K^EI a matrix over its basic DOFs. ``dof`` is then the first
    basic DOF.

    ``ref`` (a structure DOF index; None: the ground) puts a one-DOF element between ``dof`` and
    ``ref``, as a storey between two floors: its displacement is u[dof] - u[ref] (the drift the
    actuator imposes) and its force R acts as +R on ``dof`` and -R on ``ref`` (the element's
    incidence, :attr:`Structure.incidence`).
    """

    name: str
    dof: int
    specimen: dict
    actuator: str = ""
    K_EI_declared: float | tuple | None = None
    dofs: tuple[int, ...] = ()
    actuators: tuple[str, ...] = ()
    setup: dict | None = None
    displacement_from: str = ""  # an external instrument's name; "" = the actuator's transducer
    outer_loop: OuterLoop | None = None
    ref: int | None = None  # the other end of a one-DOF element; None: the ground

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name.strip():
            raise ConfigError(f"experimental element: name must be a non-empty string, got {self.name!r}")
        what = f"experimental element {self.name!r}"
        _index(what, "dof", self.dof)
        if not isinstance(self.dofs, (tuple, list)):
            raise ConfigError(f"{what}: dofs must be a tuple of DOF indices, got {self.dofs!r}")
        for k, d in enumerate(self.dofs):
            _index(what, f"dofs[{k}]", d)
        if not isinstance(self.specimen, dict):
            raise ConfigError(f"{what}: specimen must be a table such as {{'kind': 'linear', 'k': 1.0}}, "
                              f"got {self.specimen!r}")
        if not self.is_multi_dof:  # a multi-DOF model is built with its setup (model())
            _check_specimen(what, self.specimen)
        if isinstance(self.K_EI_declared, (int, float, np.number)) and not isinstance(self.K_EI_declared, bool):
            _checker(what).number("K_EI_declared", float(self.K_EI_declared), positive=True)
        elif self.K_EI_declared is not None:
            try:
                K = np.array(self.K_EI_declared, dtype=float)
            except (TypeError, ValueError):
                K = None
            if K is None or K.ndim != 2 or K.shape[0] != K.shape[1] or not np.all(np.isfinite(K)):
                raise ConfigError(f"{what}: K_EI_declared must be a positive number or a square matrix of finite "
                                  f"numbers, got {self.K_EI_declared!r}")
            n = len(self.dofs) if self.dofs else 1
            if K.shape != (n, n):
                raise ConfigError(f"{what}: K_EI_declared must be a {n} x {n} matrix (a row per basic DOF), got "
                                  f"{K.shape[0]} x {K.shape[1]}")
            if not np.allclose(K, K.T, rtol=0, atol=1e-12 * np.max(np.abs(K))):
                raise ConfigError(f"{what}: K_EI_declared must be symmetric")
            try:
                np.linalg.cholesky(K)
            except np.linalg.LinAlgError:
                raise ConfigError(f"{what}: K_EI_declared must be positive definite") from None
            # one basic DOF: K^EI is a number; several: rows of numbers, as a structure file gives them
            object.__setattr__(self, "K_EI_declared", float(K[0, 0]) if n == 1 else tuple(tuple(r) for r in K.tolist()))
        if not self.actuator:
            object.__setattr__(self, "actuator", self.actuators[0] if self.actuators else self.name)
        if self.dofs and self.dof != self.dofs[0]:
            object.__setattr__(self, "dof", self.dofs[0])
        if self.ref is not None:
            _index(what, "ref", self.ref)
            if self.has_setup or self.is_multi_dof:
                raise ConfigError(f"{what}: ref: an element between two DOFs has one basic DOF and no setup; an element "
                                  "loaded through a setup acts on its basic DOFs (docs/setups.md)")
            if self.ref == self.dof:
                raise ConfigError(f"{what}: ref: the element joins DOF {self.dof} to itself")

    @property
    def basic_dofs(self) -> tuple[int, ...]:
        """The structure DOFs of the element's basic DOFs, in order."""
        return tuple(self.dofs) if self.dofs else (self.dof,)

    @property
    def actuator_names(self) -> tuple[str, ...]:
        return tuple(self.actuators) if self.actuators else (self.actuator,)

    @property
    def is_parallel(self) -> bool:
        """Loaded by several actuators in parallel on one basic DOF (setup kind ``parallel``)."""
        return isinstance(self.setup, dict) and self.setup.get("kind") == "parallel"

    @property
    def has_setup(self) -> bool:
        """Loaded through a setup (strokes are not the basic displacements one to one)."""
        return self.setup is not None or len(self.basic_dofs) > 1

    @property
    def is_multi_dof(self) -> bool:
        from hsio.specimens.matrix import MATRIX_KINDS

        return self.specimen.get("kind") in MATRIX_KINDS

    def make_setup(self):
        """The element's setup (identity when it names none)."""
        from hsio.setups import make_setup

        return make_setup(self.setup if self.setup is not None else {"kind": "none"}, len(self.basic_dofs),
                          f"experimental element {self.name!r}: setup")

    def model(self):
        if self.is_multi_dof:
            from hsio.specimens.matrix import make_matrix_specimen

            basic = getattr(self.make_setup(), "basic", None) or None
            return make_matrix_specimen(self.specimen, basic)
        return make_specimen(self.specimen)

    @property
    def K_EI(self):
        """A number for a one-DOF element, the matrix over the basic DOFs otherwise."""
        if self.K_EI_declared is not None:
            if isinstance(self.K_EI_declared, (int, float)):
                return float(self.K_EI_declared)
            return np.array(self.K_EI_declared, dtype=float)
        return self.model().initial_stiffness

    @property
    def K_EI_matrix(self) -> np.ndarray:
        """K^EI over the basic DOFs, always a matrix."""
        n = len(self.basic_dofs)
        K = np.atleast_2d(np.asarray(self.K_EI, dtype=float))
        if K.shape == (1, 1) and n > 1:
            raise ConfigError(f"experimental element {self.name!r}: K_EI must be a {n} x {n} matrix")
        return K


# A static preload's ramp (lab time): at most an hour, as a record; at least 0.1 s, five times the
# emulated force loop's 20 ms lag (a shorter ramp is a step of force on the specimen).
MIN_RAMP_S, MAX_RAMP_S = 0.1, 3600.0


def ramp_out_of_bounds(ramp_s: float) -> str:
    """Why a preload's ``ramp_s`` is refused ("" when it is within the bounds)."""
    if ramp_s > MAX_RAMP_S:
        return f"{ramp_s:g} s is out of bounds: a preload's ramp lasts at most {MAX_RAMP_S:g} s (lab time)"
    if ramp_s < MIN_RAMP_S:
        return (f"{ramp_s:g} s is out of bounds: a preload's ramp lasts at least {MIN_RAMP_S:g} s (a shorter one "
                f"puts the preload on the specimen as a step of force)")
    return ""


def dt_out_of_bounds(dt: float) -> str:
    """Why a structure's time step ``dt`` is refused ("" when it is within the bounds)."""
    from hsio.ground_motion import DT_MAX_S, DT_MIN_S

    if DT_MIN_S <= dt <= DT_MAX_S:
        return ""
    return f"{dt:g} s is out of bounds: the integration time step must be within {DT_MIN_S:g}..{DT_MAX_S:g} s"


@dataclass(frozen=True)
class StaticLoad:
    """An actuator tied to no dynamic DOF: it ramps a preload (an axial gravity load, say) in force
    control before the test, holds it while the other DOFs run, and ramps it off at the end
    (docs/setups.md). ``specimen`` is what it loads (the emulator's model of it), ``force_kN`` the
    preload, ``ramp_s`` the lab time of each ramp; ``K_EI_declared`` the stiffness the lab declares
    for what it loads (None: the model's initial stiffness), over which its ramps' rod velocity and
    its held displacement are predicted."""

    name: str
    force_kN: float
    specimen: dict
    ramp_s: float = 5.0
    actuator: str = ""
    K_EI_declared: float | None = None

    def __post_init__(self):
        if not self.actuator:
            object.__setattr__(self, "actuator", self.name)
        check = _checker(f"static load {self.name!r}")
        if check.number("force_kN", self.force_kN) == 0:
            raise ConfigError(f"static load {self.name!r}: force_kN: a preload of zero needs no static actuator")
        wrong = ramp_out_of_bounds(check.number("ramp_s", self.ramp_s, positive=True))
        if wrong:
            raise ConfigError(f"static load {self.name!r}: ramp_s: {wrong}")
        _check_specimen(f"static load {self.name!r}", self.specimen)
        if self.K_EI_declared is not None:
            check.number("K_EI_declared", self.K_EI_declared, positive=True)

    has_setup = False
    is_parallel = False
    is_multi_dof = False

    @property
    def actuator_names(self) -> tuple[str, ...]:
        return (self.actuator,)

    def model(self) -> Specimen:
        return make_specimen(self.specimen)

    @property
    def K_EI(self) -> float:
        """The stiffness of what the preload loads: the declared one, else the model's initial
        stiffness. The preload's displacement and the rod velocity of its ramps are predicted over it."""
        return float(self.K_EI_declared) if self.K_EI_declared is not None else float(self.model().initial_stiffness)


INSTRUMENT_KINDS = {"lvdt": "mm", "string_pot": "mm", "load_cell": "kN", "strain_gauge": "microstrain"}


@dataclass(frozen=True)
class Instrument:
    """An external instrument read every step (docs/setups.md): an LVDT or string pot (mm) on
    the specimen, a load cell (kN), a strain gauge (microstrain). ``element`` is what it measures
    in emulation: the specimen displacement of that element's actuator (lvdt, string_pot), its
    force (load_cell) or ``scale`` microstrain per kN of it (strain_gauge)."""

    name: str
    kind: str
    element: str = ""
    scale: float = 1.0
    noise: float = 0.0
    resolution: float = 0.0

    @property
    def unit(self) -> str:
        return INSTRUMENT_KINDS[self.kind]


@dataclass(frozen=True)
class OuterLoop:
    """Correct the command until the external instrument reads the target within
    ``tolerance_mm``, at most ``max_iterations`` extra commands per step (docs/setups.md)."""

    tolerance_mm: float = 0.02
    max_iterations: int = 5


@dataclass(frozen=True)
class Spring:
    """A numerical linear spring between DOF i and j (j = None: to the ground), k in kN/mm.

    Springs make K_N, the linear part of the numerical restoring force R^N = K_N u + ...
    """

    i: int
    j: int | None
    k: float
    name: str = ""

    def __post_init__(self):
        what = f"spring {self.name!r}" if self.name else "spring"
        _index(what, "i", self.i)
        if self.j is not None:
            _index(what, "j", self.j)
        _checker(what).number("k", self.k, positive=True)


@dataclass(frozen=True)
class NumericalElement:
    """A numerical element with a specimen model, between DOF ``dof`` and ``to`` (None: ground).

    Its deformation is u[dof] - u[to]; its force F acts as +F on ``dof`` and -F on ``to``.
    """

    name: str
    i: int
    specimen: dict
    j: int | None = None

    def __post_init__(self):
        what = f"numerical element {self.name!r}"
        _index(what, "i", self.i)
        if self.j is not None:
            _index(what, "j", self.j)
        if not isinstance(self.specimen, dict):
            raise ConfigError(f"{what}: specimen must be a table such as {{'kind': 'linear', 'k': 1.0}}, "
                              f"got {self.specimen!r}")
        _check_specimen(what, self.specimen)

    @property
    def dof(self) -> int:
        """The DOF of an element to the ground (an element between two DOF has two: i and j)."""
        if self.j is not None:
            raise ConfigError(f"numerical element {self.name!r} joins two DOF ({self.i}, {self.j}); "
                              "use Structure.numerical_assembly() for its force")
        return self.i

    def model(self) -> Specimen:
        return make_specimen(self.specimen)


def incidence(dofs, refs, n: int) -> np.ndarray:
    """The incidence matrix E (elements x DOFs) of elements at ``dofs``, each to its ``refs`` entry
    (None or no ``refs``: to the ground): +1 at the element's DOF, -1 at its reference DOF."""
    dofs = np.asarray(dofs, dtype=int).reshape(-1)
    outside = [int(d) for d in dofs if not 0 <= d < n]
    if outside:
        raise ConfigError(f"element_dofs: DOF {outside[0]} is not in 0..{n - 1} (one DOF index per element)")
    refs = [None] * dofs.size if refs is None else list(refs)
    if len(refs) != dofs.size:
        raise ConfigError(f"element_refs: {len(refs)} for {dofs.size} elements (one per element; None: the ground)")
    E = np.zeros((dofs.size, n))
    E[np.arange(dofs.size), dofs] = 1.0
    for j, r in enumerate(refs):
        if r is None:
            continue
        if isinstance(r, (bool, np.bool_)) or not isinstance(r, (int, np.integer)) or not 0 <= r < n or r == dofs[j]:
            raise ConfigError(f"element_refs[{j}]: must be None (the ground) or a DOF in 0..{n - 1} other than the "
                              f"element's own ({int(dofs[j])}), got {r!r}")
        E[j, r] = -1.0
    return E


def _add_between(K: np.ndarray, i: int, j: int | None, k: float) -> None:
    """Add the stiffness k of an element between DOF i and j (j None: ground) to K."""
    K[i, i] += k
    if j is not None:
        K[j, j] += k
        K[i, j] -= k
        K[j, i] -= k


DAMPING_KINDS = ("mass", "stiffness", "rayleigh", "modal")


@dataclass(frozen=True)
class Damping:
    """Viscous damping C from the ratio(s) zeta, of the structure's initial stiffness K_I.

    * ``mass``: C = 2 zeta w_m M, ratio zeta on mode m = ``modes[0]`` (default 1);
    * ``stiffness``: C = 2 zeta / w_m K, ratio zeta on mode m;
    * ``rayleigh``: C = a0 M + a1 K with ratio zeta_i on modes i, j = ``modes`` (default 1, 2);
      ``zeta`` is one ratio or one per mode;
    * ``modal``: C = M Phi diag(2 zeta_r w_r) Phi^T M (Phi mass-normalised), ratio zeta_r on
      every mode r; ``zeta`` is one ratio or one per mode.

    Modes are numbered from 1 by increasing frequency.
    """

    zeta: float | tuple[float, ...] = 0.05
    kind: str = "rayleigh"
    modes: tuple[int, ...] = ()

    def __post_init__(self):
        for key in ("zeta", "modes"):  # numpy arrays (one ratio or mode per entry) as tuples of numbers
            value = getattr(self, key)
            if isinstance(value, np.ndarray):
                object.__setattr__(self, key, tuple(value.tolist()) if value.ndim == 1 else value.tolist())

    def mode_numbers(self) -> tuple[int, ...]:
        if self.modes:
            return tuple(self.modes)
        return (1, 2) if self.kind == "rayleigh" else (1,)

    def ratios(self, count: int) -> tuple[float, ...]:
        z = self.zeta
        if isinstance(z, (int, float)):
            return (float(z),) * count
        if len(z) != count:
            raise ConfigError(f"damping {self.kind!r}: {len(z)} ratios for {count} modes")
        return tuple(float(v) for v in z)

    def check(self, n: int) -> None:
        """The kind is known and, unless modal, its modes exist among the ``n`` of the structure."""
        if self.kind not in DAMPING_KINDS:
            raise ConfigError(f"damping kind must be one of {', '.join(DAMPING_KINDS)}, got {self.kind!r}")
        modes = self.mode_numbers()
        if self.kind != "modal" and any(not 1 <= m <= n for m in modes):
            hint = (" (Rayleigh damping takes two modes: on one DOF give Damping(zeta, kind='mass') or "
                    "kind='stiffness')") if self.kind == "rayleigh" and n == 1 else ""
            raise ConfigError(f"damping {self.kind!r} on modes {list(modes)}, but the structure has {n} mode(s){hint}")

    def matrix(self, M: np.ndarray, K: np.ndarray) -> np.ndarray:
        n = M.shape[0]
        self.check(n)
        if self.kind == "modal":
            w2, phi = scipy.linalg.eigh(K, M)
            zeta = np.asarray(self.ratios(n))
            Mphi = M @ phi
            return Mphi @ np.diag(2 * zeta * np.sqrt(w2)) @ Mphi.T
        modes = self.mode_numbers()
        omega = np.sqrt(np.sort(scipy.linalg.eigh(K, M, eigvals_only=True)))
        if self.kind in ("mass", "stiffness"):
            (zeta,) = self.ratios(1)
            w = omega[modes[0] - 1]
            return 2 * zeta * w * M if self.kind == "mass" else 2 * zeta / w * K
        if len(modes) != 2 or modes[0] == modes[1]:
            raise ConfigError(f"rayleigh damping needs two different modes, got {list(modes)}")
        z1, z2 = self.ratios(2)
        w1, w2 = omega[modes[0] - 1], omega[modes[1] - 1]
        if z1 == z2:
            a0 = 2 * z1 * w1 * w2 / (w1 + w2)
            a1 = 2 * z1 / (w1 + w2)
        else:  # zeta_r = a0 / (2 w_r) + a1 w_r / 2 on both modes
            a0, a1 = np.linalg.solve([[1 / (2 * w1), w1 / 2], [1 / (2 * w2), w2 / 2]], [z1, z2])
        return a0 * M + a1 * K


@dataclass(frozen=True)
class Structure:
    """A structure for hybrid simulation, in kN, mm, s (mass in kN s^2/mm).

    ``masses`` are lumped per DOF; ``mass_matrix`` (if given) is the full M instead, and
    ``masses`` then becomes its diagonal (whatever was passed for it).
    ``influence`` is the excitation direction per DOF (the influence vector iota, default 1).
    """

    name: str
    dof_names: tuple[str, ...]
    masses: tuple[float, ...]
    experimental: tuple[ExperimentalElement, ...]
    springs: tuple[Spring, ...] = ()
    numerical: tuple[NumericalElement, ...] = ()
    damping: Damping = field(default_factory=Damping)
    dt: float = 0.01
    description: str = ""
    mass_matrix: tuple[tuple[float, ...], ...] | None = None
    influence: tuple[float, ...] | None = None
    source: str = ""
    static: tuple[StaticLoad, ...] = ()
    instruments: tuple[Instrument, ...] = ()

    def __post_init__(self):
        self._check_arguments()
        n = len(self.dof_names)
        if n == 0 or len(self.masses) != n:
            raise ConfigError(f"structure {self.name!r}: {len(self.masses)} masses for {n} DOF")
        if self.influence is not None and len(self.influence) != n:
            raise ConfigError(f"structure {self.name!r}: {len(self.influence)} influence coefficients for {n} DOF")
        for element in self.experimental:
            for dof in element.basic_dofs:
                if not 0 <= dof < n:
                    raise ConfigError(f"structure {self.name!r}: element {element.name!r} is at DOF {dof}, not in 0..{n - 1}")
            if element.ref is not None and not 0 <= element.ref < n:
                raise ConfigError(f"structure {self.name!r}: element {element.name!r}: ref (its other end) is DOF "
                                  f"{element.ref}, not in 0..{n - 1}")
        for e in (*self.springs, *self.numerical):
            if not 0 <= e.i < n or (e.j is not None and not 0 <= e.j < n) or e.i == e.j:
                raise ConfigError(f"structure {self.name!r}: {e} must join a DOF in 0..{n - 1} to another or to the ground")
        dofs = self.experimental_dofs
        if len(set(dofs)) != len(dofs):
            raise ConfigError(f"structure {self.name!r}: two experimental elements share a DOF")
        self._check_rotations()
        actuators = [a for e in (*self.experimental, *self.static) for a in e.actuator_names]
        if len(set(actuators)) != len(actuators):
            raise ConfigError(f"structure {self.name!r}: two experimental elements share an actuator")
        try:
            self.damping.check(n)
        except ConfigError as exc:
            raise ConfigError(f"structure {self.name!r}: {exc}") from None
        self._check_record_names()
        self._check_model()

    def _check_rotations(self) -> None:
        """A setup's rotation (its basic DOF ``theta``, in rad) is no translation: an element
        between two DOFs joins two translations (its displacement, the drift u[dof] - u[ref], is
        in mm), a spring or a numerical element joins a rotation to the ground or to another
        rotation only, and a ground translation does not rotate it (iota = 0: the load
        P = -M iota a_g is a force, a_g a translation's acceleration)."""
        if not any(e.setup is not None for e in self.experimental):
            return
        rotations = rotation_dofs(self)
        if not rotations:
            return
        where = self.source or f"structure {self.name!r}"
        for k, e in enumerate(self.experimental):
            if e.ref is not None and e.ref in rotations:
                raise ConfigError(f"{where}: experimental[{k}].ref: DOF {self.dof_names[e.ref]!r} is a rotation (the "
                                  f"basic DOF theta of a setup, in rad); an element between two DOFs joins two "
                                  f"translations (its drift u[dof] - u[ref] is in mm)")
        for key, elements in (("spring", self.springs), ("numerical", self.numerical)):
            for k, e in enumerate(elements):
                if e.j is not None and (e.i in rotations) != (e.j in rotations):
                    raise ConfigError(f"{where}: {key}[{k}]: joins DOF {self.dof_names[e.i]!r} to "
                                      f"{self.dof_names[e.j]!r}, a rotation (rad) to a translation (mm); join a "
                                      "rotation to the ground or to another rotation")
        for r in sorted(rotations):
            if self.iota[r] != 0.0:
                key = f"dof[{r}].iota" if self.source else f"influence[{r}]"
                raise ConfigError(f"{where}: {key}: DOF {self.dof_names[r]!r} is a rotation (the basic DOF theta of a "
                                  f"setup, in rad), which a ground translation does not turn: its iota must be 0, "
                                  f"got {self.iota[r]:g} (iota is 1 unless given)")

    def _check_arguments(self) -> None:
        """Each argument is of its type and holds finite numbers where numbers are due (the
        structure-file loader's checks, docs/structures.md, for a structure built in code)."""
        what = self.source or f"structure {self.name!r}"
        check = _checker(what)
        check.string("name", self.name)  # run records, plots and folders carry it
        sequences = {"dof_names": self.dof_names, "masses": self.masses}
        if self.influence is not None:
            sequences["influence"] = self.influence
        for key, value in sequences.items():
            if isinstance(value, (str, bytes, dict)) or not isinstance(value, (tuple, list, np.ndarray)):
                raise ConfigError(f"{what}: {key}: must be a tuple (one per DOF), got {value!r}")
            object.__setattr__(self, key, tuple(float(v) if isinstance(v, np.number) else v for v in value))
        seen: dict[str, int] = {}
        for k, name in enumerate(self.dof_names):
            check.string(f"dof_names[{k}]", name)
            if name in seen:
                raise ConfigError(f"{what}: dof_names[{k}]: DOF {name!r} is declared twice")
            seen[name] = k
        for k, m in enumerate(self.masses):
            check.number(f"masses[{k}]", m, positive=self.mass_matrix is None)
        if self.influence is not None:
            iota = [check.number(f"influence[{k}]", v) for k, v in enumerate(self.influence)]
            if iota and not any(iota):
                raise ConfigError(f"{what}: influence: every DOF has iota = 0: the ground motion would load none of them")
        for key, kind in (("experimental", ExperimentalElement), ("springs", Spring), ("numerical", NumericalElement),
                          ("static", StaticLoad), ("instruments", Instrument)):
            object.__setattr__(self, key, _elements(what, key, getattr(self, key), kind))
        if not isinstance(self.damping, Damping):
            raise ConfigError(f"{what}: damping: must be a Damping, got {self.damping!r}")
        check.check_instruments(self.experimental, self.instruments)
        wrong = dt_out_of_bounds(check.number("dt", self.dt, positive=True))
        if wrong:
            raise ConfigError(f"{what}: dt: {wrong}")
        if self.mass_matrix is not None:
            rows = self.mass_matrix
            if isinstance(rows, np.ndarray):
                rows = rows.tolist()
            if not isinstance(rows, (tuple, list)) or any(not isinstance(r, (tuple, list, np.ndarray)) for r in rows):
                raise ConfigError(f"{what}: mass_matrix: must be {len(self.dof_names)} rows of "
                                  f"{len(self.dof_names)} numbers, got {self.mass_matrix!r}")
            rows = [list(r) for r in rows]
            try:
                M = check.mass_matrix({"matrix": rows}, len(self.dof_names))
            except ConfigError as exc:  # the file's key, mass.matrix, is the argument mass_matrix here
                raise ConfigError(str(exc).replace(": mass.matrix", ": mass_matrix", 1)) from None
            object.__setattr__(self, "mass_matrix", tuple(tuple(float(v) for v in r) for r in M))
            object.__setattr__(self, "masses", tuple(float(v) for v in np.diag(M)))  # what M lumps at each DOF

    # columns of the record's instruments table beside one per instrument
    INSTRUMENT_TABLE_COLUMNS = ("step", "iterations")

    def _check_record_names(self) -> None:
        """Every name the record writes as a column is its own column there: DOFs, recorded
        channels (:func:`channel_names`), elements (:attr:`experimental_names`, the implicit
        methods' table), actuators (the elements' and the preloads') and instruments, each kept to letters,
        digits and _ and compared ignoring case, as SQLite compares column names
        (hsio.recording.column). Two that would share one (``"A"`` and ``"a"``, ``"lvdt-1"`` and
        ``"lvdt_1"``, an element named ``"column.x"`` beside element ``column``'s channel on DOF
        ``x``) are refused here, before a run opens anything, rather than when its first step is written."""
        from hsio.recording import column

        what = self.source or f"structure {self.name!r}"
        channels = list(recorded_channels(self))
        # the implicit methods' table: a column per element (element.dof per basic DOF of one on several)
        elements = [(f"experimental[{k}].name", e.name if len(e.basic_dofs) == 1 else f"{e.name}.{self.dof_names[d]}")
                    for k, e in enumerate(self.experimental) for d in e.basic_dofs]
        groups = (
            ("DOF", [(f"dof[{k}].name", name) for k, name in enumerate(self.dof_names)], ()),
            ("recorded channel", channels, ()),
            ("element", elements, ()),
            ("actuator", list(self._actuator_keys()), ()),
            ("instrument", [(f"instrument[{k}].name", i.name) for k, i in enumerate(self.instruments)],
             self.INSTRUMENT_TABLE_COLUMNS),
        )
        for what_kind, names, reserved in groups:
            seen: dict[str, tuple[str, str]] = {}
            for where, name in names:
                key = column("", name)[1:].casefold()
                if key in reserved:
                    raise ConfigError(f"{what}: {where}: {what_kind} name {name!r} is a column the record's "
                                      f"{what_kind}s table keeps for itself ({', '.join(reserved)}); give another")
                if key in seen:
                    first_where, first = seen[key]
                    if first == name:
                        raise ConfigError(f"{what}: {where}: {what_kind} {name!r} is also the {what_kind} of "
                                          f"{first_where}; give names that differ")
                    raise ConfigError(f"{what}: {where}: {what_kind} {name!r} and {first!r} of {first_where} would be "
                                      "one column of the record (it keeps the letters, digits and _ of a name and "
                                      "ignores case); give names that differ there")
                seen[key] = (where, name)
        # a DOF's columns are u_, v_, a_, u_pred_, R_ (r_) and mode_ + its name: DOF "pred_x"'s u_ column
        # is DOF "x"'s u_pred_ column
        dofs = {column("", name)[1:].casefold(): (f"dof[{k}].name", name) for k, name in enumerate(self.dof_names)}
        for key, (where, name) in dofs.items():
            if key.startswith("pred_") and key[len("pred_"):] in dofs:
                first_where, first = dofs[key[len("pred_"):]]
                raise ConfigError(f"{what}: {where}: DOF {name!r} would make the column {column('u', name)!r} of the "
                                  f"record, which is the predicted displacement (u_pred_) of DOF {first!r} of "
                                  f"{first_where}; give another name")

    def _actuator_keys(self):
        """Per actuator of the loop (the elements', then the preloads'), the structure file's key
        that names it and its name: the record keeps a column per actuator (its interlocks,
        compensation and preload tables)."""
        for k, e in enumerate(self.experimental):
            if not e.actuators:
                yield f"experimental[{k}].{'name' if e.actuator == e.name else 'actuator'}", e.actuator
                continue
            for j, a in enumerate(e.actuators):  # named after the element where the file names none
                yield (f"experimental[{k}].name" if a.startswith(f"{e.name}.") or a == e.name
                       else f"experimental[{k}].actuators[{j}]" if len(e.actuators) > 1 else f"experimental[{k}].actuator"), a
        for k, load in enumerate(self.static):
            yield f"static[{k}].{'name' if load.actuator == load.name else 'actuator'}", load.actuator

    def _check_model(self) -> None:
        """The damping ratios are fractions of critical, K_I is not singular and no mode gets a
        negative damping ratio (the loader's checks)."""
        check = _checker(self.source or f"structure {self.name!r}")
        zeta = self.damping.zeta
        table = {"kind": self.damping.kind, "zeta": list(zeta) if isinstance(zeta, (tuple, list)) else zeta}
        if self.damping.modes:
            table["modes"] = list(self.damping.modes)
        check.damping(table, self.n_dof)
        check.check_stable(self)
        check.check_damping(self)

    @property
    def n_dof(self) -> int:
        return len(self.dof_names)

    @property
    def M(self) -> np.ndarray:
        if self.mass_matrix is not None:
            return np.array(self.mass_matrix, dtype=float)
        return np.diag(np.asarray(self.masses, dtype=float))

    @property
    def iota(self) -> np.ndarray:
        """Influence vector of the ground acceleration: P(t) = -M iota a_g(t)."""
        if self.influence is None:
            return np.ones(self.n_dof)
        return np.asarray(self.influence, dtype=float)

    @property
    def K_N(self) -> np.ndarray:
        """Stiffness matrix of the numerical linear springs."""
        K = np.zeros((self.n_dof, self.n_dof))
        for s in self.springs:
            _add_between(K, s.i, s.j, s.k)
        return K

    @property
    def K_EI(self) -> np.ndarray:
        """Initial stiffness of the experimental elements, K^EI = E^T K^EI_basic E over the
        structure's DOFs (:attr:`incidence`): diagonal but for elements between two DOFs and
        elements with several basic DOFs, whose blocks couple them."""
        E = self.incidence
        return E.T @ self.K_EI_basic @ E

    @property
    def K_EI_basic(self) -> np.ndarray:
        """K^EI over the experimental channels (every element's basic DOFs, in order): block diagonal."""
        blocks = [e.K_EI_matrix for e in self.experimental]
        return scipy.linalg.block_diag(*blocks) if blocks else np.zeros((0, 0))

    @property
    def has_setups(self) -> bool:
        return any(e.has_setup or e.is_multi_dof for e in self.experimental)

    @property
    def K_num_init(self) -> np.ndarray:
        """Initial stiffness of the numerical elements (with specimen models)."""
        K = np.zeros((self.n_dof, self.n_dof))
        for e in self.numerical:
            _add_between(K, e.i, e.j, e.model().initial_stiffness)
        return K

    @property
    def K_init(self) -> np.ndarray:
        """Initial stiffness of the whole structure: the implicit stiffness K_I of alpha-OS."""
        return self.K_EI + self.K_N + self.K_num_init

    @property
    def C(self) -> np.ndarray:
        return self.damping.matrix(self.M, self.K_init)

    def modes(self) -> tuple[np.ndarray, np.ndarray]:
        """Circular frequencies (rad/s, increasing) and mass-normalised mode shapes of (K_I, M)."""
        w2, phi = scipy.linalg.eigh(self.K_init, self.M)
        return np.sqrt(w2), phi

    def natural_frequencies_hz(self) -> np.ndarray:
        w2 = scipy.linalg.eigh(self.K_init, self.M, eigvals_only=True)
        return np.sqrt(np.sort(w2)) / (2 * np.pi)

    def damping_ratios(self) -> np.ndarray:
        """zeta_r = phi_r^T C phi_r / (2 w_r), per mode (exact for classical damping)."""
        omega, phi = self.modes()
        return np.sum(phi * (self.C @ phi), axis=0) / (2 * omega)  # phi_r^T C phi_r, one product

    @property
    def experimental_dofs(self) -> list[int]:
        """The structure DOF of each experimental channel: every element's basic DOFs, in order."""
        return [d for e in self.experimental for d in e.basic_dofs]

    @property
    def experimental_refs(self) -> list[int | None]:
        """Per experimental channel, the other end of its element (``ref``; None: the ground)."""
        return [e.ref for e in self.experimental for _ in e.basic_dofs]

    @property
    def incidence(self) -> np.ndarray:
        """E, channels x DOFs: channel j's displacement is (E u)_j = u[dof_j] - u[ref_j] (u[ground]
        = 0), and the channels' forces R act on the structure's DOFs as E^T R."""
        return incidence(self.experimental_dofs, self.experimental_refs, self.n_dof)

    @property
    def experimental_names(self) -> list[str]:
        """One name per experimental channel: the element's name, or ``element.dof`` for an
        element with several basic DOFs."""
        names = []
        for e in self.experimental:
            if len(e.basic_dofs) == 1:
                names.append(e.name)
            else:
                names += [f"{e.name}.{self.dof_names[d]}" for d in e.basic_dofs]
        return names

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
        self.models = [e.model() for e in structure.numerical]
        self.K_linear = structure.K_N.copy()
        self.K_initial = structure.K_N + structure.K_num_init
        self.is_linear = all(m.kind == "linear" for m in self.models)
        if self.is_linear:
            self.K_linear = self.K_initial.copy()

    def trial(self, u: np.ndarray, dt: float = 0.0) -> np.ndarray:
        """R^N at ``u`` from the committed state (committed state unchanged)."""
        u = np.asarray(u, dtype=float)
        R = self.structure.K_N @ u
        for e, model in zip(self.structure.numerical, self.models):
            deformation = u[e.i] - (u[e.j] if e.j is not None else 0.0)
            F = model.trial(float(deformation), dt)
            R[e.i] += F
            if e.j is not None:
                R[e.j] -= F
        return R

    def commit(self) -> None:
        for model in self.models:
            model.commit()


def recorded_channels(structure: Structure):
    """Per recorded channel, the structure file's key that names it and its name: an element on
    one DOF without a setup is recorded under its actuator's name (``experimental[k].actuator``,
    or ``.name`` when the actuator is named after the element); an element with several basic
    DOFs or a setup under ``element.dof`` per DOF (``experimental[k].name``)."""
    for k, e in enumerate(structure.experimental):
        if len(e.basic_dofs) == 1 and not e.has_setup:
            yield f"experimental[{k}].{'name' if e.actuator == e.name else 'actuator'}", e.actuator
        else:
            for d in e.basic_dofs:
                yield f"experimental[{k}].name", f"{e.name}.{structure.dof_names[d]}"


def channel_names(structure: Structure) -> list[str]:
    """The recorded channels (:func:`recorded_channels`), in order."""
    return [name for _, name in recorded_channels(structure)]

def rotation_dofs(structure: Structure) -> set[int]:
    """The DOFs the structure says are rotations (rad, their forces moments in kN mm): the basic
    DOFs ``theta`` of its elements' planar setups (docs/setups.md). Every other DOF is taken as a
    translation (mm, kN)."""
    out: set[int] = set()
    for e in structure.experimental:
        if e.setup is None:
            continue
        basic = getattr(e.make_setup(), "basic", ())
        out.update(d for d, b in zip(e.basic_dofs, basic) if b == "theta")
    return out


def dof_units(structure: Structure) -> list[str]:
    """Per DOF, the unit of its displacement: "rad" for a rotation (:func:`rotation_dofs`), else "mm"."""
    rotations = rotation_dofs(structure)
    return ["rad" if k in rotations else "mm" for k in range(len(structure.dof_names))]


def channel_units(structure: Structure) -> list[tuple[str, str]]:
    """Per recorded channel (:func:`channel_names`), the units of its displacement and force:
    ("rad", "kN mm") on a rotation, else ("mm", "kN")."""
    rotations = rotation_dofs(structure)
    return [("rad", "kN mm") if d in rotations else ("mm", "kN") for d in structure.experimental_dofs]


def sdof(m: float = 1.0, k: float = 4 * np.pi**2, zeta: float = 0.0, dt: float = 0.01, specimen: dict | None = None) -> Structure:
    """A single-DOF structure with one experimental element (linear unless ``specimen`` says)."""
    if specimen is not None and not isinstance(specimen, dict):
        raise ConfigError(f"sdof: specimen must be a table such as {{'kind': 'linear', 'k': 1.0}}, got {specimen!r}")
    return Structure(
        name="sdof",
        dof_names=("x",),
        masses=(m,),
        experimental=(ExperimentalElement("x", 0, {"kind": "linear", "k": k} if specimen is None else specimen),),
        damping=Damping(zeta, "mass"),
        dt=dt,
    )


def validation() -> Structure:
    """The validation structure (E&M 2007, Table I), from the shipped file."""
    return get_structure("validation")


def structure_I() -> Structure:
    """Test structure I (E&M 2007, Table II), from the shipped file."""
    return get_structure("structure_I")


def structure_II() -> Structure:
    """Test structure II (E&M 2007, Table III), from the shipped file."""
    return get_structure("structure_II")


def get_structure(name: str) -> Structure:
    """A shipped structure by name (``validation``, ``structure_I``, ``structure_II``, ...)."""
    from hsio.structure_file import load_shipped

    return load_shipped(name)


def load_structure(path_or_name, relative_to=None) -> Structure:
    """A structure from a structure file (path, relative to ``relative_to`` if given) or a
    shipped name; see docs/structures.md."""
    from hsio.structure_file import load_structure as _load

    return _load(path_or_name, relative_to)
