"""The ``[opensees]`` table of a run configuration (docs/opensees.md).

    [opensees]
    elements = ["C1"]          # experimental elements of [structure] this server serves
    length_factor = 1.0        # mm per length unit of the OpenSees model (1000 for metres), 1e-6 to 1e6
    force_factor = 1.0         # kN per force unit of the OpenSees model (1 for kN, 0.001 for N), idem
    stiffness = "initial"      # getTangentStiff: "initial" (K^EI) or "secant" (estimated per step)
    force_correction = true    # getForce: measured force + K^EI (target - measured displacement)
    timeout_s = 60.0           # a silent element is disconnected after this long (at most 86400 s),
                               # not counting the time the actuators spend executing a motion; so
                               # is the client of a session that stopped on a fault
    mass = {}                  # per element, kN s^2/mm, answered to getMass (default 0): a number
                               # (times the identity) or a matrix over its basic DOFs
    damping = {}               # per element, kN s/mm, answered to getDamp (default 0): idem
    out = "runs/opensees"      # folder of the session records (run.sqlite, run-2.sqlite, ...),
                               # relative to the working directory as `hsio run --out`

The rest of the file is a `hsio run` configuration ([structure], [hardware], [test], ...).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hsio.errors import ConfigError

# Bounds: any unit system of a model lies well within FACTOR_RANGE (mm per km is 1e6, kN per
# N 1e-3), and a silence of more than a day is no session; beyond MAX_TIMEOUT_S a socket's
# timeout would not even fit the platform's time type.
FACTOR_RANGE = (1e-6, 1e6)
MAX_TIMEOUT_S = 86400.0

KEYS = ("elements", "length_factor", "force_factor", "stiffness", "force_correction", "timeout_s", "mass",
        "damping", "out")


@dataclass(frozen=True)
class OpenSeesSettings:
    """What the server needs beyond a run configuration."""

    elements: tuple[str, ...]
    length_factor: float = 1.0
    force_factor: float = 1.0
    stiffness: str = "initial"
    force_correction: bool | None = None  # None: [test] measured_displacement_correction
    timeout_s: float = 60.0
    mass: dict = field(default_factory=dict)
    damping: dict = field(default_factory=dict)
    out: str = "runs/opensees"


def _number(where: str, key: str, value, positive: bool = True) -> float:
    value = _finite(where, key, value)
    if positive and not value > 0:
        raise ConfigError(f"{where}: {key} must be positive, got {value!r}")
    if not positive and value < 0:
        raise ConfigError(f"{where}: {key} must not be negative, got {value!r}")
    return float(value)


def _bounded(where: str, key: str, value, low: float, high: float) -> float:
    value = _number(where, key, value)
    if not low <= value <= high:
        raise ConfigError(f"{where}: {key} must be between {low:g} and {high:g}, got {value!r}")
    return value


def _matrix(where: str, key: str, value) -> tuple[tuple[float, ...], ...]:
    """A square, symmetric matrix of finite numbers given as a list of rows."""
    n = len(value)
    if not n or not all(isinstance(row, list) and len(row) == n for row in value):
        raise ConfigError(f"{where}: {key} must be a number or a square matrix (a list of {n or 'n'} rows of "
                          f"{n or 'n'} numbers), got {value!r}")
    rows = tuple(tuple(_number(where, f"{key}[{i}][{k}]", x, positive=False) if i == k else
                       _finite(where, f"{key}[{i}][{k}]", x) for k, x in enumerate(row)) for i, row in enumerate(value))
    for i in range(n):
        for k in range(i):
            if rows[i][k] != rows[k][i]:
                raise ConfigError(f"{where}: {key} must be symmetric: [{i}][{k}] = {rows[i][k]:g} but "
                                  f"[{k}][{i}] = {rows[k][i]:g}")
    eigenvalues = np.linalg.eigvalsh(np.array(rows))
    if eigenvalues.min() < -1e-12 * max(abs(eigenvalues).max(), 1e-300):
        raise ConfigError(f"{where}: {key} must be positive semidefinite (a mass or damping matrix); its smallest "
                          f"eigenvalue is {eigenvalues.min():.4g}")
    return rows


def _finite(where: str, key: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(f"{where}: {key} must be a finite number, got {value!r}")
    return float(value)


def _per_element(where: str, key: str, value, elements) -> dict:
    """Per served element: a number (times the identity over its basic DOFs) or a matrix over them."""
    if not isinstance(value, dict):
        raise ConfigError(f"{where}: {key} must be a table of element = value, got {value!r}")
    out = {}
    for name, x in value.items():
        if name not in elements:
            raise ConfigError(f"{where}: {key} names {name!r}, not one of the served elements {list(elements)}")
        if isinstance(x, list):
            out[name] = _matrix(where, f"{key}.{name}", x)
        else:
            out[name] = _number(where, f"{key}.{name}", x, positive=False)
    return out


def parse(table, source: str) -> OpenSeesSettings:
    where = f"{source}: [opensees]"
    if not isinstance(table, dict):
        raise ConfigError(f"{where} must be a table, got {table!r}")
    unknown = sorted(set(table) - set(KEYS))
    if unknown:
        raise ConfigError(f"{where}: unknown key {unknown[0]!r}; known: {', '.join(KEYS)}")
    elements = table.get("elements")
    if (not isinstance(elements, list) or not elements or not all(isinstance(e, str) and e for e in elements)
            or len(set(elements)) != len(elements)):
        raise ConfigError(f"{where}: elements must be a non-empty list of distinct element names, got {elements!r}")
    stiffness = table.get("stiffness", "initial")
    if stiffness not in ("initial", "secant"):
        raise ConfigError(f"{where}: stiffness must be 'initial' or 'secant', got {stiffness!r}")
    correction = table.get("force_correction")
    if correction is not None and not isinstance(correction, bool):
        raise ConfigError(f"{where}: force_correction must be true or false, got {correction!r}")
    out = table.get("out", "runs/opensees")
    if not isinstance(out, str) or not out:
        raise ConfigError(f"{where}: out must be a folder name, got {out!r}")
    return OpenSeesSettings(
        elements=tuple(elements),
        length_factor=_bounded(where, "length_factor", table.get("length_factor", 1.0), *FACTOR_RANGE),
        force_factor=_bounded(where, "force_factor", table.get("force_factor", 1.0), *FACTOR_RANGE),
        stiffness=stiffness, force_correction=correction,
        timeout_s=_bounded(where, "timeout_s", table.get("timeout_s", 60.0), 0.0, MAX_TIMEOUT_S),
        mass=_per_element(where, "mass", table.get("mass", {}), elements),
        damping=_per_element(where, "damping", table.get("damping", {}), elements),
        out=out,
    )


def split_config(path: str | Path):
    """A server configuration file as (OpenSeesSettings, RunConfig): the [opensees] table parsed
    here, the rest checked as `hsio run` checks it (relative paths resolved beside the file)."""
    from hsio import config as config_mod

    path = Path(path)
    data = config_mod.read_toml(path, "server configuration")
    if "opensees" not in data:
        raise ConfigError(f"{path}: no [opensees] table: say which elements this server serves, "
                          f"e.g. [opensees] elements = [\"C1\"]")
    settings = parse(data.pop("opensees"), str(path))
    run = config_mod.from_dict(data, str(path))
    config_mod.resolve_paths(run, path)
    return settings, run


# What a server never reads of a run configuration: it has no record of its own (OpenSees sends
# the motion), no integrator (OpenSees integrates), no dry run (it cannot predict the analysis),
# no plots, no NS and no specimen ledger. Written there, they are named at start.
UNREAD_TABLES = ("record", "integrator", "specimen")
UNREAD_KEYS = {"test": ("start",), "output": ("plots", "ns"),
               "safety": ("dry_run", "override", "stroke_margin", "force_margin", "velocity_margin")}


def unread_settings(run) -> list[str]:
    """The settings written in a server's configuration that the server does not read, as
    ``[table] key`` (empty when there are none)."""
    given = run.given
    out = [f"[{t}] {k}" for t in UNREAD_TABLES for k in sorted(given.get(t, ()))]
    out += [f"[{t}] {k}" for t, keys in UNREAD_KEYS.items() for k in keys if k in given.get(t, ())]
    return out
