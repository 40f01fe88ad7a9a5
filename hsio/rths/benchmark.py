"""The benchmark's data: reference model, partitioning cases, experimental substructure, record.

Silva et al. (2020): a 3-storey frame, the reference model M x'' + C x' + K x = -M iota a_g, is
split at the first floor. The experimental substructure is (m_e, c_e, k_e) at DOF 1; the
numerical substructure is the reference model less those, loaded by the ground motion and by the
measured restoring force f_m of the specimen:

    M_n x'' + C_n x' + K_n x = -M iota a_g - [f_m, 0, 0]^T

(M_n = M - m_e e1 e1^T and likewise for C and K). Everything here is in SI units (kg, N, m, s).
"""

from __future__ import annotations

import json
import math
import numbers
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
from scipy import signal

FS = 4096.0  # controller rate, Hz (benchmark constraint)
RECORD_SCALE = 0.4  # El Centro 1940 x 0.4
MAX_RECORD_S = 1000.0  # longest record run (the benchmark's lasts 41.18 s)
MIN_RECORD_S = 0.5  # shortest (as `--duration`): J1-J9 need samples to compare
MAX_RECORD_ACCEL = 100.0  # m/s^2, about 10 g: a larger value is a record in other units (cm/s^2, mm/s^2)
# The record of the paper's Table 3 (El Centro 1940 as the benchmark's package holds it, unscaled):
# its samples, their spacing and its peak. Another record gets no Table 3 beside its results.
TABLE3_RECORD = dict(samples=2060, dt_s=0.02, peak_m_s2=3.135)


@dataclass(frozen=True)
class Benchmark:
    """benchmark.json and the unscaled El Centro record, as read from ``folder``."""

    data: dict
    record_t: np.ndarray
    record_a: np.ndarray

    @property
    def cases(self) -> list[int]:
        return sorted(int(c) for c in self.data["cases"])

    def is_table3_record(self) -> bool:
        """The record is the one of the paper's Table 3 (TABLE3_RECORD; its time may start anywhere)."""
        t, a, ref = self.record_t, self.record_a, TABLE3_RECORD
        return (t.size == ref["samples"] and bool(np.allclose(np.diff(t), ref["dt_s"], rtol=1e-6, atol=1e-9))
                and abs(float(np.max(np.abs(a))) - ref["peak_m_s2"]) <= 1e-3 * ref["peak_m_s2"])

    def table3(self, case: int) -> list[float] | None:
        """The paper's J1-J9 of the sample controller for ``case`` (None when the data lack them,
        or when the record is not the one the table was made with)."""
        if not self.is_table3_record():
            return None
        table = self.data.get("table3_sample_controller_elcentro")
        row = table.get(str(case)) if isinstance(table, dict) else None
        try:
            return [float(j) for j in row] if row is not None and len(row) == 9 else None
        except (TypeError, ValueError):
            return None


def load(folder: str | Path) -> Benchmark:
    """Read and check the data folder; anything the benchmark cannot run on is a ValueError
    naming the file and what is wrong there. Kept while neither file changes (size and mtime)."""
    folder = Path(folder)
    stamps = []
    for name in ("benchmark.json", "elcentro_vrths.csv"):
        try:
            st = (folder / name).stat()
        except OSError as exc:  # missing, or the folder cannot be read: named as the rest of the data
            raise ValueError(f"{folder / name}: cannot read the benchmark's data: {exc.strerror}") from None
        stamps.append((st.st_size, st.st_mtime_ns))
    return _load(str(folder.resolve()), tuple(stamps))


@lru_cache(maxsize=4)
def _load(folder: str, _stamps: tuple) -> Benchmark:
    folder = Path(folder)
    js = folder / "benchmark.json"
    try:
        data = json.loads(js.read_text(encoding="utf-8"))
    except ValueError as exc:  # JSON that does not parse, bytes that are no UTF-8
        raise ValueError(f"{js}: {exc}") from None
    csv = folder / "elcentro_vrths.csv"
    rec, lines = _read_record(csv)
    bm = Benchmark(data, rec[:, 0].copy(), rec[:, 1].copy())
    check(bm, folder, lines)
    return bm


def _read_record(csv: Path) -> tuple[np.ndarray, list[int]]:
    """The record's rows of numbers (n x 2) and the line of the file each one is on (blank lines
    and # comments are skipped). The first line is the header time_s,accel_m_s2."""
    try:
        text = csv.read_text(encoding="utf-8-sig")
    except ValueError as exc:  # bytes that are no UTF-8
        raise ValueError(f"{csv}: {exc}") from None
    rows, lines = [], []
    for number, line in enumerate(text.splitlines(), start=1):
        line = line.split("#", 1)[0].strip()
        if number == 1:
            if _numbers(line):
                raise ValueError(f"{csv}:1: {line!r} is a row of numbers; the first line is the header "
                                 "time_s,accel_m_s2 (a record without one would lose its first sample)")
            continue
        if not line:
            continue
        try:
            rows.append([float(x) for x in line.split(",")])
        except ValueError:
            raise ValueError(f"{csv}:{number}: {line[:60]!r} is not comma-separated numbers time_s,accel_m_s2") from None
        lines.append(number)
    width = len(rows[0]) if rows else 0
    if len(rows) < 2 or any(len(r) != 2 for r in rows):
        raise ValueError(f"{csv}: needs a header and at least two rows of time_s,accel_m_s2 "
                         f"(has {len(rows)} rows of {width} columns)")
    return np.array(rows, dtype=float), lines


def _numbers(line: str) -> bool:
    """The line is comma-separated numbers (a data row, not a header)."""
    try:
        [float(x) for x in line.split(",")]
    except ValueError:
        return False
    return True


def check(bm: Benchmark, folder: Path, lines: list[int] | None = None) -> None:
    """The record: at least two finite rows, time increasing over MIN_RECORD_S to MAX_RECORD_S, accelerations
    within MAX_RECORD_ACCEL, a ground that moves; benchmark.json: every number the cases, the plant and the constraints
    need (3 x 3 matrices for each case, finite, a mass that leaves the numerical substructure a
    positive definite one, a stable reference model, the substructure's me, ke and the converters'
    scales positive, a stable control plant)."""
    from hsio.rths import plant as plant_mod

    csv, js = folder / "elcentro_vrths.csv", folder / "benchmark.json"
    line = (lambda i: lines[i]) if lines is not None else (lambda i: i + 2)  # noqa: E731  the file's line of row i
    t, a = bm.record_t, bm.record_a
    bad = np.flatnonzero(~(np.isfinite(t) & np.isfinite(a)))
    if bad.size:
        raise ValueError(f"{csv}:{line(int(bad[0]))}: a value that is not a finite number")
    back = np.flatnonzero(np.diff(t) <= 0.0)
    if back.size:
        raise ValueError(f"{csv}:{line(int(back[0]) + 1)}: time does not increase ({t[back[0]]:g} s, then {t[back[0] + 1]:g} s)")
    if t[-1] - t[0] < MIN_RECORD_S:
        raise ValueError(f"{csv}: the record lasts {t[-1] - t[0]:g} s; the benchmark needs at least {MIN_RECORD_S:g} s")
    if t[-1] - t[0] > MAX_RECORD_S:
        raise ValueError(f"{csv}: the record lasts {t[-1] - t[0]:g} s; the benchmark runs at most {MAX_RECORD_S:g} s "
                         f"at {FS:g} Hz (is the time column in seconds?)")
    big = np.flatnonzero(np.abs(a) > MAX_RECORD_ACCEL)
    if big.size:
        raise ValueError(f"{csv}:{line(int(big[0]))}: an acceleration of {a[big[0]]:g} m/s^2, beyond {MAX_RECORD_ACCEL:g} "
                         "m/s^2 (about 10 g; is the record in m/s^2, not cm/s^2?)")
    if not np.any(a != 0.0):
        raise ValueError(f"{csv}: the ground never moves (every acceleration is 0)")
    if not isinstance(bm.data, dict) or not isinstance(bm.data.get("cases"), dict) or not bm.data["cases"]:
        raise ValueError(f"{js}: needs a 'cases' table of partitioning cases")
    try:
        numbers = [case(bm, int(c)) for c in bm.data["cases"]]
        plant = plant_mod.nominal(bm.data)
        std = [float(bm.data["plant"]["std"][k]) for k in plant_mod.UNCERTAIN]
    except (KeyError, TypeError, ValueError, IndexError, OverflowError) as exc:
        raise ValueError(f"{js}: a case, the plant or a constraint is missing or not a number: "
                         f"{type(exc).__name__} {exc}") from None
    values = [getattr(plant, f) for f in plant.__dataclass_fields__] + std
    if not all(np.isfinite(values)) or min(plant.me, plant.ke, plant.m_per_V, plant.N_per_V, plant.quantum_V) <= 0.0:
        raise ValueError(f"{js}: the plant, the substructure and the constraints need finite numbers, "
                         "me, ke and the converters' scales positive")
    _check_constraints(bm.data["constraints"], js)
    for cs in numbers:
        for name in ("M", "C", "K"):
            m = getattr(cs, name)
            if m.shape != (3, 3) or not np.all(np.isfinite(m)):
                raise ValueError(f"{js}: cases.{cs.number}.{name} must be a 3 x 3 matrix of finite numbers")
        if not np.allclose(cs.M, cs.M.T) or np.min(np.linalg.eigvalsh(cs.Mn)) <= 0.0:
            raise ValueError(f"{js}: cases.{cs.number}.M must be symmetric, and positive definite less the "
                             f"specimen's me = {cs.me:g} kg at the first floor (the numerical substructure's mass)")
        A, _ = _second_order_ss(cs.M, cs.C, cs.K, np.zeros((3, 1)))
        if np.max(np.linalg.eigvals(A).real) >= 0.0:
            raise ValueError(f"{js}: cases.{cs.number}: the reference model M x'' + C x' + K x = 0 is not stable "
                             "(K and C must make every mode decay)")
    if min(std) < 0.0:
        raise ValueError(f"{js}: plant.std: the standard deviations of {', '.join(plant_mod.UNCERTAIN)} must not be "
                         f"negative (got {', '.join(f'{v:g}' for v in std)})")
    if np.max(np.linalg.eigvals(plant.continuous()[0]).real) >= 0.0:
        raise ValueError(f"{js}: the control plant (servo-valve, actuator, specimen in the unity displacement "
                         "loop, eqs. 21-22) is not stable with these parameters")


def _check_constraints(c: dict, js: Path) -> None:
    """The implementation constraints the loop uses: its rate (FS, which hsio runs at), the
    converters' bits, a force saturation above zero, a noise that is not negative, and the stroke and
    velocity limits a run is reported against (positive numbers where given)."""
    def number(key: str) -> float:
        try:
            value = float(c[key])
        except (TypeError, ValueError):
            value = math.nan
        if not math.isfinite(value):
            raise ValueError(f"{js}: constraints.{key} must be a finite number (got {c[key]!r})")
        return value

    if "sampling_hz" in c and number("sampling_hz") != FS:
        raise ValueError(f"{js}: constraints.sampling_hz is {c['sampling_hz']}; the benchmark runs at {FS:g} Hz")
    bits = number("adc_dac_bits")
    if bits != int(bits) or not 1 <= bits <= 32:
        raise ValueError(f"{js}: constraints.adc_dac_bits must be a whole number of bits from 1 to 32 (got {c['adc_dac_bits']})")
    if not number("max_force_N") > 0.0:
        raise ValueError(f"{js}: constraints.max_force_N, the actuator's force saturation, must be above 0 "
                         f"(got {c['max_force_N']})")
    if not number("noise_rms_V") >= 0.0:
        raise ValueError(f"{js}: constraints.noise_rms_V must not be negative (got {c['noise_rms_V']})")
    for key in ("stroke_mm", "max_velocity_mm_s"):
        if key in c and not number(key) > 0.0:
            raise ValueError(f"{js}: constraints.{key} must be above 0 (got {c[key]!r})")


def ground_motion(bm: Benchmark, duration: float | None = None, fs: float = FS) -> np.ndarray:
    """a_g at the controller rate (m/s^2): the record x 0.4, linearly interpolated. The whole
    record by default, from its first sample (whatever its time); with ``duration``, that many
    seconds from the last quiet sample before the ground starts to move (the record opens with
    5 s of zeros, during which nothing happens)."""
    t0 = bm.record_t[0]
    t_end = bm.record_t[-1]
    if duration is not None:
        t0, available = moving_span(bm)
        if isinstance(duration, bool) or not (isinstance(duration, numbers.Real) and math.isfinite(duration)
                                              and duration >= MIN_RECORD_S):
            raise ValueError(f"duration = {duration!r} s: give a finite duration of {MIN_RECORD_S:g} s or more")
        if duration > available + 0.5 / fs:  # a cut, never a silent clamp
            raise ValueError(f"duration = {duration:g} s is longer than the record ({available:g} s from the first "
                             "motion); give None to run the whole record")
        t_end = min(t0 + duration, t_end)
    n = int(np.floor((t_end - t0) * fs + 1e-9)) + 1
    t = t0 + np.arange(n) / fs
    return RECORD_SCALE * np.interp(t, bm.record_t, bm.record_a)


def moving_span(bm: Benchmark) -> tuple[float, float]:
    """The time of the last quiet sample before the ground starts to move, and the seconds of
    record from there to its end (what ``ground_motion`` can cut a duration from)."""
    moving = np.flatnonzero(bm.record_a != 0.0)
    t0 = float(bm.record_t[max(int(moving[0]) - 1, 0)] if moving.size else bm.record_t[0])
    return t0, float(bm.record_t[-1]) - t0


@dataclass(frozen=True)
class Case:
    """One partitioning case: the reference model and the numerical substructure."""

    number: int
    M: np.ndarray
    C: np.ndarray
    K: np.ndarray
    me: float
    ce: float
    ke: float

    @property
    def Mn(self) -> np.ndarray:
        return self.M - self.me * _e1e1()

    @property
    def Cn(self) -> np.ndarray:
        return self.C - self.ce * _e1e1()

    @property
    def Kn(self) -> np.ndarray:
        return self.K - self.ke * _e1e1()

    def with_specimen_stiffness(self, ke_actual: float) -> "Case":
        """The reference model when the physical specimen's stiffness is ``ke_actual`` (a perturbed
        plant): the numerical substructure keeps the nominal partition, the specimen changes."""
        K = self.K + (ke_actual - self.ke) * _e1e1()
        return Case(self.number, self.M, self.C, K, self.me, self.ce, ke_actual)


def _e1e1() -> np.ndarray:
    e = np.zeros((3, 3))
    e[0, 0] = 1.0
    return e


def case(bm: Benchmark, number: int) -> Case:
    if str(number) not in bm.data["cases"]:
        raise ValueError(f"case {number}: the benchmark has cases {bm.cases}")
    c = bm.data["cases"][str(number)]
    ex = bm.data["experimental_substructure"]
    return Case(number, np.array(c["M"], float), np.array(c["C"], float), np.array(c["K"], float),
                float(ex["me_kg"]), float(ex["ce_kg_s"]), float(ex["ke_N_m"]))


def reference_response(M: np.ndarray, C: np.ndarray, K: np.ndarray, ag: np.ndarray, fs: float = FS) -> np.ndarray:
    """Floor displacements (n x 3) of the reference model for a_g linearly interpolated
    between samples: the first-order-hold discretisation is exact for that input. It runs in
    the eigenvectors of the discrete state matrix, one first-order recursion (lfilter) each."""
    A, B = _second_order_ss(M, C, K, M @ np.ones(3)[:, None] * -1.0)
    Cy = np.hstack([np.eye(3), np.zeros((3, 3))])
    Ad, Bd, Cd, Dd, _ = signal.cont2discrete((A, B, Cy, np.zeros((3, 1))), 1.0 / fs, method="foh")
    lam, V = np.linalg.eig(Ad)
    b = np.linalg.solve(V, Bd[:, 0])
    a = np.asarray(ag, float)
    # xi[k] = sum_i V[:, i] q_i[k],  q_i[k+1] = lam_i q_i[k] + b_i a[k],  q_i[0] = 0
    q = np.empty((lam.size, a.size), complex)
    for i in range(lam.size):
        q[i] = signal.lfilter([0.0, b[i]], [1.0, -lam[i]], a)
    y = (Cd @ V @ q).real.T + a[:, None] * Dd[:, 0]
    return y


def _second_order_ss(M, C, K, F):
    """x = [u; u'], x' = A x + B w for M u'' + C u' + K u = F w."""
    n = M.shape[0]
    Mi = np.linalg.inv(M)
    A = np.block([[np.zeros((n, n)), np.eye(n)], [-Mi @ K, -Mi @ C]])
    B = np.vstack([np.zeros((n, F.shape[1])), Mi @ F])
    return A, B


@dataclass(frozen=True)
class NumericalSubstructure:
    """The numerical substructure discretised at the controller rate (zero-order hold on a_g and
    f_m): z[k+1] = Ad z[k] + Bd [a_g, f_m]; the first floor's acceleration is Ca z + Da [a_g, f_m]."""

    Ad: np.ndarray
    Bd: np.ndarray
    Ca: np.ndarray
    Da: np.ndarray


def numerical_substructure(cs: Case, fs: float = FS) -> NumericalSubstructure:
    F = np.hstack([-cs.M @ np.ones((3, 1)), -np.array([[1.0], [0.0], [0.0]])])
    A, B = _second_order_ss(cs.Mn, cs.Cn, cs.Kn, F)
    Ad, Bd, *_ = signal.cont2discrete((A, B, np.eye(6), np.zeros((6, 2))), 1.0 / fs, method="zoh")
    return NumericalSubstructure(np.ascontiguousarray(Ad), np.ascontiguousarray(Bd),
                                 np.ascontiguousarray(A[3]), np.ascontiguousarray(B[3]))
