"""Multi-DOF specimens: basic forces q from basic displacements d (docs/setups.md).

An experimental element loaded through a setup has several basic DOFs (a column top in
translation and rotation, a joint in x, y and rotation). Its specimen model gives the vector of
basic forces q (kN, or kN mm for a rotation) at the vector of basic displacements d (mm, rad),
with the same trial/commit contract as the one-dimensional models of :mod:`hsio.specimens`.

:class:`LinearMatrix` is q = K d with a symmetric positive-definite K;
:func:`cantilever_top_stiffness` gives K for the top of a fixed-base column (Euler-Bernoulli,
with the axial stiffness EA/L when the vertical DOF is among the basic DOFs).
"""

from __future__ import annotations

import math

import numpy as np

from hsio.errors import ConfigError

MATRIX_KINDS = ("matrix", "cantilever")
CANTILEVER_DOFS = ("ux", "uy", "theta")


def cantilever_top_stiffness(EI: float, L: float, EA: float = 0.0, basic=("ux", "theta")) -> np.ndarray:
    """The stiffness of the top of a vertical cantilever of height ``L`` (mm), flexural rigidity
    ``EI`` (kN mm^2) and axial rigidity ``EA`` (kN), over ``basic`` out of (ux, uy, theta):

        [[12 EI/L^3, 0,    6 EI/L^2],
         [0,         EA/L, 0       ],
         [6 EI/L^2,  0,    4 EI/L  ]]

    x is lateral, y up along the column, theta counter-clockwise (a top pushed to +x with its
    rotation held needs a counter-clockwise moment, hence the positive coupling).
    """
    for name, value in (("EI", EI), ("L", L)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise ConfigError(f"cantilever: {name} must be a positive number, got {value!r}")
    if any(b not in CANTILEVER_DOFS for b in basic) or len(set(basic)) != len(basic) or not basic:
        raise ConfigError(f"cantilever: basic DOFs must be distinct names out of {', '.join(CANTILEVER_DOFS)}, "
                          f"got {list(basic)}")
    if "uy" in basic and not EA > 0:
        raise ConfigError("cantilever: the vertical DOF uy needs a positive axial rigidity EA")
    EI, L, EA = np.float64(EI), np.float64(L), np.float64(EA)
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        full = np.array([[12 * EI / L**3, 0.0, 6 * EI / L**2],
                         [0.0, EA / L, 0.0],
                         [6 * EI / L**2, 0.0, 4 * EI / L]])
    index = [CANTILEVER_DOFS.index(b) for b in basic]
    K = full[np.ix_(index, index)]
    if not np.all(np.isfinite(K)):
        raise ConfigError(f"cantilever: EI = {float(EI):g}, L = {float(L):g}, EA = {float(EA):g} give a stiffness "
                          "beyond the floating-point range (check the units: kN mm^2, mm, kN)")
    return K


class LinearMatrix:
    """q = K d over n basic DOFs; K symmetric positive definite."""

    kind = "matrix"

    def __init__(self, K):
        K = np.array(K, dtype=float)
        if K.ndim != 2 or K.shape[0] != K.shape[1] or K.shape[0] == 0:
            raise ConfigError(f"matrix specimen: K must be square, got shape {K.shape}")
        if not np.all(np.isfinite(K)):
            raise ConfigError("matrix specimen: K must be finite")
        scale = float(np.max(np.abs(K)))
        if not np.allclose(K, K.T, rtol=0.0, atol=1e-12 * scale):
            raise ConfigError("matrix specimen: K must be symmetric")
        try:
            np.linalg.cholesky(K)
        except np.linalg.LinAlgError:
            raise ConfigError("matrix specimen: K must be positive definite") from None
        self.K = K
        self.n = K.shape[0]
        self._trial = np.zeros(self.n)

    @property
    def initial_stiffness(self) -> np.ndarray:
        return self.K.copy()

    def trial(self, d, dt: float = 0.0) -> np.ndarray:
        d = np.asarray(d, dtype=float)
        if d.shape != (self.n,):
            raise ConfigError(f"matrix specimen: {d.size} basic displacements for {self.n} basic DOFs")
        self._trial = d.copy()
        return self.K @ d

    def commit(self) -> None:
        pass

    def revert_to_start(self) -> None:
        self._trial = np.zeros(self.n)

    def force(self, d, dt: float = 0.0) -> np.ndarray:
        return self.trial(d, dt)

    def displacement_for_force(self, q) -> np.ndarray:
        """The basic displacements that carry basic forces ``q`` (force control)."""
        return np.linalg.solve(self.K, np.asarray(q, dtype=float))


def make_matrix_specimen(spec: dict, basic=None) -> LinearMatrix:
    """A multi-DOF specimen from a table: ``{kind = "matrix", K = [[...], ...]}`` or
    ``{kind = "cantilever", EI = ..., L = ..., EA = ...}`` (over the setup's ``basic`` DOFs)."""
    kind = spec.get("kind")
    if kind == "matrix":
        if set(spec) - {"kind", "K"}:
            raise ConfigError(f"matrix specimen: unknown key(s) {sorted(set(spec) - {'kind', 'K'})}; known: K")
        if "K" not in spec:
            raise ConfigError("matrix specimen: K missing")
        return LinearMatrix(spec["K"])
    if kind == "cantilever":
        known = {"kind", "EI", "L", "EA"}
        if set(spec) - known:
            raise ConfigError(f"cantilever specimen: unknown key(s) {sorted(set(spec) - known)}; known: EI, L, EA")
        if basic is None:
            raise ConfigError("cantilever specimen: needs a setup that names its basic DOFs (ux, uy, theta)")
        return LinearMatrix(cantilever_top_stiffness(spec.get("EI", 0.0), spec.get("L", 0.0), spec.get("EA", 0.0), basic))
    raise ConfigError(f"unknown multi-DOF specimen kind {kind!r}; known: {', '.join(MATRIX_KINDS)}")
