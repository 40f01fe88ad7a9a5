"""The result of a run: histories as arrays, one row per integration step (row 0: the initial state).

Per DOF: ``u``, ``v``, ``a`` (mm, mm/s, mm/s^2), the predicted displacement ``u_pred`` and the
restoring force ``R`` (kN) the integrator used, the control mode of the DOF. Per experimental
element: what the integrator asked for (``targets``: mm in displacement control, kN in force
control), the last command the actuator was sent, the measured displacement and force, the
commands sent in the step (``iterations``), the secant stiffness of eq. (11) and the displacement
and force solutions computed in parallel (docs/method.md sections 3 and 5).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hsio.errors import HsioError


@dataclass(frozen=True)
class Switch:
    """A change of control mode of one element (docs/method.md section 5)."""

    step: int
    time_s: float
    dof: str
    to: str  # "displacement" or "force"
    within_step: bool  # a fall-back from FC to DC inside a step
    secant_kN_mm: float
    force_kN: float
    # why: "rule" (the thresholds at the end of a step), or within a step "secant below K_d",
    # "not converging" (fallback_after commands without reaching the tolerance), "force outside
    # the FC range" (fc_force_limit / explored_fraction)
    reason: str = "rule"

    def as_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class Result:
    """Histories of a run (HS or NS), one row per step; typed, no free-form keys."""

    structure: str
    method: str
    dt: float
    dof_names: tuple[str, ...]
    element_names: tuple[str, ...]
    element_dofs: tuple[int, ...]
    t: np.ndarray
    u: np.ndarray
    v: np.ndarray
    a: np.ndarray
    u_pred: np.ndarray
    R: np.ndarray
    modes: np.ndarray  # steps x DOF: "displacement" or "force"
    targets: np.ndarray  # steps x elements: the integrator's command (mm, or kN in FC)
    commands: np.ndarray  # the last command the actuator was sent
    measured_displacement: np.ndarray
    measured_force: np.ndarray
    iterations: np.ndarray  # commands sent per step and element
    converged: np.ndarray  # per step: False when j_max was reached before the tolerance
    secant: np.ndarray  # secant stiffness per step and element (kN/mm; nan: no estimate)
    u_solution: np.ndarray  # displacement solution per element (what DC commands)
    R_solution: np.ndarray  # force solution per element (what FC commands)
    switches: list[Switch] = field(default_factory=list)
    thresholds: dict | None = None
    secant_refused: list | None = None  # FC estimates of eq. (11) turned away per element (eq. 11a); None: rule off
    guarded_steps: int = 0  # mixed: steps an FC element ran in DC for its force range (fc_force_limit, explored_fraction)
    step_wall_time_s: np.ndarray | None = None
    wall_time_s: float = 0.0
    lab_time_s: float | None = None
    late_steps: int = 0
    stopped: str = ""
    # on actuators with static preloads or external instruments (docs/setups.md)
    static_log: list = field(default_factory=list)  # (phase, lab time s, targets, forces, displacements)
    static_hold_error: np.ndarray | None = None  # per preload: max |measured - preload| / preload in the record
    # per ramp ("ramp_in", "ramp_off"), per preload: peak measured rod speed (mm/s) and |displacement| (mm)
    static_ramps: dict = field(default_factory=dict)
    instrument_log: list = field(default_factory=list)  # (trial, outer-loop iterations, readings)
    # per DOF, the unit of its displacement: "rad" for a rotation, "mm" otherwise (all "mm" when not given)
    dof_units: tuple[str, ...] = ()

    def unit_of_dof(self, k: int) -> str:
        """The unit of DOF ``k``'s displacement ("mm" or "rad"); its forces are kN or kN mm."""
        return self.dof_units[k] if k < len(self.dof_units) else "mm"

    def __repr__(self) -> str:
        """One line: what ran, on what, for how long (the histories are its arrays)."""
        stopped = f", stopped={self.stopped!r}" if self.stopped else ""
        return (f"Result(structure={self.structure!r}, method={self.method!r}, steps={self.steps}, dt={self.dt!r}, "
                f"dof_names={self.dof_names!r}, element_names={self.element_names!r}{stopped})")

    @property
    def steps(self) -> int:
        """Integration steps made (row 0 is the initial state)."""
        return len(self.t) - 1

    @property
    def force_control(self) -> np.ndarray:
        """Steps x elements: true where the element ran the step in force control."""
        return self.modes[:, list(self.element_dofs)] == "force"

    def tracking_error(self) -> np.ndarray:
        """Target minus measured displacement at the end of each step, per element (mm).

        In force-control steps the target is the displacement solution computed in parallel
        (what displacement control would have commanded), so the error stays in mm."""
        targets = np.where(self.force_control, self.u_solution, self.targets)
        return targets - self.measured_displacement

    def to_dataframe(self):
        """The per-step histories as a pandas DataFrame indexed by step (pandas is optional:
        ``pip install hsio[dataframe]``)."""
        try:
            import pandas as pd
        except ImportError:  # pragma: no cover - depends on the installation
            from hsio.errors import HsioError

            raise HsioError("Result.to_dataframe needs pandas: pip install 'hsio[dataframe]'") from None
        columns: dict[str, np.ndarray] = {"time_s": self.t}
        for k, name in enumerate(self.dof_names):
            for prefix, values in (("u", self.u), ("v", self.v), ("a", self.a), ("u_pred", self.u_pred), ("R", self.R),
                                   ("mode", self.modes)):
                columns[f"{prefix}_{name}"] = values[:, k]
        for j, name in enumerate(self.element_names):
            for prefix, values in (("target", self.targets), ("command", self.commands),
                                   ("disp", self.measured_displacement), ("force", self.measured_force),
                                   ("iterations", self.iterations), ("secant", self.secant)):
                columns[f"{prefix}_{name}"] = values[:, j]
        frame = pd.DataFrame(columns)
        frame.index.name = "step"
        return frame

    def plot(self, path: str | Path | None = None, reference: "Result | None" = None):
        """Displacement of each DOF (against ``reference``, e.g. NS, when given) and the
        force-displacement loops of each element; a matplotlib Figure, saved to ``path`` if given."""
        from hsio import plots

        if reference is not None and not isinstance(reference, Result):
            raise HsioError(f"plot: reference must be a Result (e.g. hsio.run_numerical(...)), got "
                            f"{type(reference).__name__}")
        if reference is not None and tuple(reference.dof_names) != tuple(self.dof_names):
            raise HsioError(f"plot: the reference is a run of other DOFs ({', '.join(map(str, reference.dof_names))}; "
                            f"this run: {', '.join(map(str, self.dof_names))})")
        if path is not None:
            if not isinstance(path, (str, os.PathLike)):
                raise HsioError(f"plot: path must be a file path, got {type(path).__name__}")
            if Path(path).is_dir():
                raise HsioError(f"plot: {path} is a folder; give the image file's path (e.g. {Path(path) / 'run.png'})")
        figure = plots.result_figure(self, reference, None)
        if path is not None:
            try:
                figure.savefig(path, dpi=110)
            except (OSError, ValueError) as exc:
                raise HsioError(f"plot: cannot write {path}: {getattr(exc, 'strerror', None) or exc}") from None
        return figure


def max_error_pct(u_hs: np.ndarray, u_ns: np.ndarray) -> tuple[float, list[float]]:
    """Max over time and DOF of |u_HS - u_NS| / peak |u_NS| of that DOF, in percent; and per DOF.

    Both are histories (steps x DOF) of the same DOF; the shorter one (a run stopped early) sets
    the steps compared. Two :class:`Result` objects are compared by their ``u``. A DOF that NS
    leaves at rest (peak 0) is compared with 1 mm: its error in hundredths of a millimetre."""
    u_hs, u_ns = (x.u if isinstance(x, Result) else x for x in (u_hs, u_ns))
    try:
        u_hs, u_ns = np.asarray(u_hs, dtype=float), np.asarray(u_ns, dtype=float)
    except (TypeError, ValueError):
        raise HsioError(f"max_error_pct: u_hs and u_ns must be histories of numbers (steps x DOF) or Results, got "
                        f"{type(u_hs).__name__} and {type(u_ns).__name__}") from None
    if u_hs.ndim != 2 or u_ns.ndim != 2 or u_hs.shape[1] != u_ns.shape[1] or not len(u_hs) or not len(u_ns):
        raise HsioError(f"max_error_pct: u_hs and u_ns must be histories (steps x DOF) of the same DOF, got shapes "
                        f"{u_hs.shape} and {u_ns.shape}")
    n = min(len(u_hs), len(u_ns))
    if not (np.all(np.isfinite(u_hs[:n])) and np.all(np.isfinite(u_ns[:n]))):
        raise HsioError("max_error_pct: a history holds values that are not finite (a run that diverged?); "
                        "the error is not defined")
    peak = np.max(np.abs(u_ns[:n]), axis=0)
    peak = np.where(peak > 0, peak, 1.0)
    per_dof = np.max(np.abs(u_hs[:n] - u_ns[:n]), axis=0) / peak * 100.0
    return float(np.max(per_dof)), [float(x) for x in per_dof]


def mode_switches(modes: np.ndarray) -> int:
    """Number of mode changes over a mode history (steps x DOF)."""
    m = np.asarray(modes)
    return int(np.sum(m[1:] != m[:-1]))
