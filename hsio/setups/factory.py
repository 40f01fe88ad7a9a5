"""Setups from the ``setup`` table of an experimental element (docs/setups.md).

``{ kind = "two_actuators", length_mm = 1500, spacing_mm = 400, factors = { displacement = 1,
force = 1 } }``; kinds and their keys are in :data:`SETUP_KINDS`.
"""

from __future__ import annotations

import math

import numpy as np

from hsio.errors import ConfigError
from hsio.setups.base import Factors, Setup
from hsio.setups.parallel import ParallelSetup
from hsio.setups.planar import inverted_v_brace, one_actuator, three_actuators, two_actuators


class IdentitySetup(Setup):
    """One actuator per basic DOF, aligned with it: stroke = displacement / factor."""

    basic: tuple[str, ...] = ()

    def __init__(self, n_basic: int, factors: Factors | None = None):
        self.n_basic = self.n_actuators = int(n_basic)
        self.factors = factors or Factors()
        self._J = np.eye(self.n_basic) / self.factors.displacement

    def strokes(self, d) -> np.ndarray:
        return self._J @ np.asarray(d, dtype=float)

    def jacobian(self, d) -> np.ndarray:
        return self._J.copy()

    def basic_displacements(self, strokes, tol: float = 1e-12, max_iter: int = 50, guess=None) -> np.ndarray:
        return np.asarray(strokes, dtype=float) * self.factors.displacement


# kind -> (factory, its keys in order, number of basic DOFs)
SETUP_KINDS = {
    "none": (None, (), None),
    "one_actuator": (one_actuator, ("length_mm", "angle_deg"), 1),
    "two_actuators": (two_actuators, ("length_mm", "spacing_mm"), 2),
    "three_actuators": (three_actuators, ("length_mm", "half_span_mm"), 3),
    "inverted_v_brace": (inverted_v_brace, ("leg_length_mm", "angle_deg"), 2),
    "parallel": (ParallelSetup, ("ratios",), 1),
}
OPTIONAL = {"one_actuator": {"angle_deg"}}  # kind -> keys with a default (0 degrees: along the DOF)


def make_setup(table: dict, n_basic: int, where: str = "setup") -> Setup:
    """A setup from its table, for an element of ``n_basic`` basic DOFs; errors name ``where``."""
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: must be a table such as {{ kind = \"two_actuators\", length_mm = 1500, "
                          f"spacing_mm = 400 }}, got {table!r}")
    kind = table.get("kind", "none")
    if not isinstance(kind, str) or kind not in SETUP_KINDS:
        raise ConfigError(f"{where}.kind: unknown setup {kind!r}; known: {', '.join(SETUP_KINDS)}")
    factory, keys, n = SETUP_KINDS[kind]
    if factory is not None and n != n_basic:
        raise ConfigError(f"{where}.kind: setup {kind!r} drives {n} basic DOF(s); the element has {n_basic} (dofs)")
    known = {"kind", "factors", *keys} | ({"mirror"} if factory not in (None, ParallelSetup) else set())
    unknown = sorted(set(table) - known)
    if unknown:
        raise ConfigError(f"{where}.{unknown[0]}: unknown key of setup {kind!r}; known: {', '.join(sorted(known))}")
    factors_table = table.get("factors", {})
    if not isinstance(factors_table, dict) or set(factors_table) - {"displacement", "force"}:
        raise ConfigError(f"{where}.factors: must be a table of displacement and force, got {factors_table!r}")
    try:
        factors = Factors(**factors_table)
    except ConfigError as exc:
        raise ConfigError(f"{where}.factors: {exc}") from None
    if factory is None:
        return IdentitySetup(n_basic, factors)
    if kind == "parallel":
        ratios = table.get("ratios")
        if not isinstance(ratios, list):
            raise ConfigError(f"{where}.ratios: {'missing' if ratios is None else f'got {ratios!r}'} (setup 'parallel' "
                              "needs ratios, an array of each actuator's stroke per unit of the DOF, e.g. [1.0, 1.0])")
        try:
            return ParallelSetup(ratios, factors)
        except ConfigError as exc:
            raise ConfigError(f"{where}.{exc}") from None
    mirror = table.get("mirror", False)
    if not isinstance(mirror, bool):
        raise ConfigError(f"{where}.mirror: must be true or false (the rig mirrored left to right, its actuators "
                          f"on the other side), got {mirror!r}")
    args = {"mirror": mirror} if "mirror" in known else {}
    for key in keys:
        if key not in table:
            if key in OPTIONAL.get(kind, ()):
                continue
            raise ConfigError(f"{where}.{key}: missing (setup {kind!r} needs {', '.join(keys)})")
        value = table[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ConfigError(f"{where}.{key}: must be a finite number, got {value!r}")
        args[key] = float(value)
    try:
        return factory(**args, factors=factors)
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None
