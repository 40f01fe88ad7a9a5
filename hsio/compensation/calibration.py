"""Calibration of the hockey stick (docs/method.md section 4, eq. 1) from a recorded run or a CSV file.

Sources:

* a run folder or its ``run.sqlite`` (:class:`hsio.recording.Run`): per step and actuator the
  command sent (``command_``, the adjusted command d^a when the run was compensated) and the
  measured displacement (``disp_``); t_d = TR dt from the run's metadata;
* a CSV file with a header ``time_s,command_mm,measured_mm`` and one row per step. time_s is the
  lab time of each step (t_d = the median step interval) unless ``test_rate`` says it is the
  record's time (t_d = TR x interval); ``t_d`` given explicitly overrides both.

The velocity of each step is the paper's v_i = (d_i - d_{i-1}) / t_d (``order=1``) or the
end-of-step velocity (``order=2``, see :func:`hockey_stick.step_velocity`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hsio.compensation import hockey_stick
from hsio.compensation.hockey_stick import D_MAX_MM, HockeyStick
from hsio.errors import HsioError, RecordError

CSV_COLUMNS = ("time_s", "command_mm", "measured_mm")
SKIP = 2  # the first steps, which have no (or only a one-sided) velocity
MIN_STEPS = 5 + SKIP  # the fit's five points after them
T_D_BOUNDS_S = (1e-5, 1e4)  # the lab duration of one step: from a 100 kHz loop to a pseudo-dynamic test's hours


@dataclass
class Calibration:
    """One actuator's calibration: the fit and the points it was fitted to."""

    actuator: str
    fit: HockeyStick
    velocity: np.ndarray  # mm/s
    error: np.ndarray  # Er, fraction of d_max
    t_d: float
    warnings: list


@dataclass
class StepData:
    """Per-step command and measurement of each actuator, and the lab duration of a step."""

    commands: dict  # actuator -> array (mm)
    measured: dict
    t_d: float
    warnings: list


def read_csv(path: Path, t_d: float | None = None, test_rate: float | None = None) -> StepData:
    """One row per step, header ``time_s,command_mm,measured_mm``; uniform time steps (gaps,
    repeats and jitter are refused with the line, by the reader of hsio diagnose)."""
    from hsio.diagnose.readers import read_csv_table
    from hsio.diagnose.record import MAX_MAGNITUDE

    def header_error(fields):
        return None if sorted(fields) == sorted(CSV_COLUMNS) else ",".join(CSV_COLUMNS)

    path, col, dt = read_csv_table(path, header_error)
    for name in ("command_mm", "measured_mm"):
        huge = np.flatnonzero(np.abs(col[name]) > MAX_MAGNITUDE)
        if huge.size:
            raise RecordError(f"{path}: {name} of data row {huge[0] + 1} is {col[name][huge[0]]:g}, beyond "
                              f"{MAX_MAGNITUDE:g} mm: no actuator moves that far; check the column")
    if col["command_mm"].size < MIN_STEPS:
        raise RecordError(f"{path}: {col['command_mm'].size} data rows; a calibration needs at least {MIN_STEPS} steps "
                          f"(the first {SKIP} give no velocity)")
    if t_d is None:
        t_d = dt * (test_rate if test_rate else 1.0)
    return StepData({"actuator": col["command_mm"]}, {"actuator": col["measured_mm"]}, float(t_d), [])


def read_run(path: Path, t_d: float | None = None) -> StepData:
    from hsio.recording import Run

    try:
        run = Run(path)
    except FileNotFoundError as exc:
        raise RecordError(str(exc)) from None
    except Exception as exc:  # sqlite3.DatabaseError and friends: an SQLite file that is no hsio run
        raise RecordError(f"{path}: not an hsio recording: {exc}") from None
    warnings = []
    config = run.meta.get("config", {})
    test = config.get("test", {})
    if test.get("hold_fraction", 0.0) > 0:
        warnings.append(f"the run used ramp-hold (hold_fraction = {test['hold_fraction']}): the actuator settles "
                        "before each measurement, so the error hardly depends on velocity; calibrate on a "
                        "continuous run ([test] hold_fraction = 0)")
    if test.get("n_avg", 1) > 1:
        warnings.append(f"the run averaged the last {test['n_avg']} samples of each step: the fitted lag includes "
                        f"{(test['n_avg'] - 1) / 2:g} controller periods of averaging")
    secant_n_avg = run.meta.get("secant_n_avg", 1)
    if config.get("integrator", {}).get("secant", "average") != "raw" and secant_n_avg > 1:
        warnings.append(f"the run's measured displacements are the secant estimator's average of the last "
                        f"{secant_n_avg} samples of each step ([integrator] secant_n_avg): the fitted lag includes "
                        f"{(secant_n_avg - 1) / 2:g} controller periods of averaging")
    in_force = [c[len("mode_"):] for c, modes in run.steps.items() if c.startswith("mode_") and "force" in set(modes)]
    if in_force:
        raise RecordError(f"{path}: DOF {', '.join(in_force)} ran steps in force control, whose commands are kN; "
                          "calibrate on a run in displacement control")
    if t_d is None:
        t_d = float(run.meta["test_rate"]) * float(run.meta["dt"])
    strokes = setup_strokes(run, config)
    if strokes is not None:
        commands, measured = strokes
    else:
        commands = {a: run.actuator("command", a) for a in run.actuator_names}  # steps 1..n
        measured = {a: run.actuator("disp", a) for a in run.actuator_names}
    return StepData(commands, measured, t_d, warnings)


def setup_strokes(run, config: dict) -> tuple[dict, dict] | None:
    """The actuators' own strokes when the run drove its elements through setups (its recorded
    channels are then basic DOFs, a rotation among them): from the compensation table, one row per
    step, the command sent d^a and the measured stroke, d^a - Er^aa d_max for a compensated
    actuator, d^c - Er^cc d_max for one that was not (d^a = d^c). None for a run without setups."""
    from hsio.recording import column

    table = run.compensation()
    found = [c[len("da_"):] for c in table if c.startswith("da_")]
    if not found or sorted(found) == sorted(column("", a)[1:] for a in run.actuator_names):
        return None
    names = {column("", a)[1:]: a for a in run.meta.get("start_state", {})}  # the names as the structure gives them
    d_max = float(config.get("compensation", {}).get("d_max_mm", D_MAX_MM))
    commands, measured = {}, {}
    for key in found:
        sent, aa, cc = table[f"da_{key}"], table[f"er_aa_{key}"], table[f"er_cc_{key}"]
        name = names.get(key, key)
        commands[name] = sent
        measured[name] = np.where(np.isfinite(aa), sent - aa * d_max, table[f"dc_{key}"] - cc * d_max)
    return commands, measured


def load(source: str | Path, t_d: float | None = None, test_rate: float | None = None) -> StepData:
    path = Path(source)
    if path.is_dir():
        path = path / "run.sqlite"
    if not path.exists():
        raise RecordError(f"{path}: no such run folder, run.sqlite or CSV file")
    if not path.is_file():  # a folder, or a FIFO or device that would be waited on for ever
        raise RecordError(f"{path}: not a regular file (a run folder, run.sqlite or CSV file)")
    if path.suffix.lower() == ".csv":
        return read_csv(path, t_d, test_rate)
    with open(path, "rb") as fh:
        magic = fh.read(16)
    if magic.startswith(b"SQLite format 3"):
        if test_rate is not None:
            raise RecordError(f"{path}: --test-rate says a CSV file's time_s is record time; a run records its "
                              "own test rate (give --t-d to set the lab duration of a step)")
        return read_run(path, t_d)
    raise RecordError(f"{path}: neither a run (SQLite) nor a CSV file with {','.join(CSV_COLUMNS)}")


def calibrate(source: str | Path, actuators: list[str] | None = None, t_d: float | None = None,
              test_rate: float | None = None, d_max_mm: float = D_MAX_MM, order: int = 1) -> list[Calibration]:
    """Fit eq. 1 to each actuator of a run (or the one of a CSV file)."""
    data = load(source, t_d, test_rate)
    if not T_D_BOUNDS_S[0] <= data.t_d <= T_D_BOUNDS_S[1]:
        raise HsioError(f"{source}: step duration t_d = {data.t_d!r} s is out of bounds: a step lasts "
                        f"{T_D_BOUNDS_S[0]:g}..{T_D_BOUNDS_S[1]:g} s of lab time (is the time column in seconds?)")
    names = list(data.commands)
    if actuators:
        unknown = [a for a in actuators if a not in data.commands]
        if unknown:
            raise HsioError(f"{source}: no actuator {', '.join(map(repr, unknown))}; the run has {', '.join(names)}")
        names = list(actuators)
    out = []
    for name in names:
        steps = len(data.commands[name])
        if steps < MIN_STEPS:
            raise RecordError(f"{source}: actuator {name!r} has {steps} steps; a calibration needs at least {MIN_STEPS} "
                              f"(the first {SKIP} give no velocity)")
        v, er = hockey_stick.from_steps(data.commands[name], data.measured[name], data.t_d, d_max_mm, order, SKIP)
        try:
            fit = hockey_stick.fit(v, er, d_max_mm)
        except hockey_stick.FitError as exc:
            raise hockey_stick.FitError(f"{source}: actuator {name!r}: {exc}") from None
        out.append(Calibration(name, fit, v, er, data.t_d, list(data.warnings) + undetermined(name, fit, v)))
    return out


def undetermined(name: str, fit: HockeyStick, velocity: np.ndarray) -> list[str]:
    """A warning when the data hardly determine the fit, by the acceptance test of the online
    estimator (hsio/compensation/online.py): too few steps beyond the threshold, or b uncertain."""
    from hsio.compensation.online import EstimatorSettings

    s = EstimatorSettings()
    beyond = int(np.count_nonzero(np.abs(velocity) > fit.a_mm_s))
    rel = fit.b_std / fit.b_s_mm if fit.b_s_mm > 0 else float("inf")
    if beyond >= s.min_beyond and rel <= s.max_rel_std:
        return []
    why = ("the run hardly moves faster than a: calibrate on a faster run (a lower test rate or a stronger record)"
           if beyond < s.min_beyond else "the error does not follow the velocity as eq. 1 says: is the run "
           "continuous, uncompensated and in displacement control?")
    return [f"actuator {name!r}: the fit is poorly determined ({beyond} steps beyond the threshold a, b uncertain "
            f"by {100 * rel:.0f} %; the online estimator accepts at least {s.min_beyond} and at most "
            f"{100 * s.max_rel_std:.0f} %): {why}"]


def plot(path: str | Path, calibrations: list[Calibration]) -> Path:
    """Execution error against command velocity with the fitted hockey stick (the paper's Fig. 8)."""
    import matplotlib

    import matplotlib.pyplot as plt

    n = len(calibrations)
    fig, axes = plt.subplots(1, n, figsize=(6.5 * n, 4.5), squeeze=False)
    for ax, cal in zip(axes[0], calibrations):
        f = cal.fit
        ax.plot(cal.velocity, cal.error * 1e3, ".", ms=2.5, color="0.45", label="measured")
        top = float(np.max(np.abs(cal.velocity))) if cal.velocity.size else 1.0
        vv = np.linspace(-top, top, 801)
        ax.plot(vv, f.error(vv) * 1e3, color="C3", lw=1.6,
                label=f"eq. 1: a = {f.a_mm_s:.3g} mm/s, b = {f.b_s_mm:.4g} s/mm (b d_max = {f.lag_s * 1e3:.1f} ms)")
        ax.axvspan(-f.a_mm_s, f.a_mm_s, color="C0", alpha=0.08)
        ax.set_xlabel("command velocity v (mm/s)")
        ax.set_ylabel("execution error Er = (d_c - d_m) / d_max  (x 1e-3)")
        ax.set_title(f"{cal.actuator}: t_d = {cal.t_d:.4g} s, {f.n} steps")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
