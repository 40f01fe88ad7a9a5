"""Error budget of a hybrid run: why the hybrid simulation (HS) differs from the numerical one (NS).

The difference D(t) = u_HS - u_NS is attributed by replaying NS with one source at a time put in:

* actuator tracking: each step's measured tracking error (target - measured displacement) less
  its transducer's noise (its white part, :func:`tracking_parts`) is imposed on the specimen
  model, and the force corrected as in HS (R = F + K^EI (d - d_m)). The physical specimen never
  moved with its transducer's noise; a hysteretic model driven along the noisy path would
  drift from it;
* measurement noise: the transducer's noise in the displacement the DAQ reads (through the
  correction it reaches the restoring force as -K^EI n_d) and the noise of each measured force,
  over the whole band (the residual of the specimen model on the measured path less the
  transducer's noise, its white level read above the response's band and its Wiener estimate
  taken in every bin: :func:`noise_estimate`), added to the model's force;
* specimen-model mismatch: the specimen model is replaced by the one the specimen diagnosis
  fits to the measured displacement and force (hsio.diagnose.specimen_fit), or by the
  structure's own model scaled to the measured force, whichever predicts the last 20 % of the
  measured force better;
* the integrator and the interaction of the sources: what the replay with every source at once
  leaves of D.

A source's share is 1 - RMS(D - Delta_s) / RMS(D), Delta_s = u_s - u_NS (the part of D its replay
reproduces); the budget accounts for A = 1 - RMS(u_HS - u_all) / RMS(D).

A main source is named only when the sources together account for at least ACCOUNTED_MIN of D
and the largest share s_1 is at least DOMINANCE times the next one's and at least 1 / DOMINANCE
of A (it carries most of what the sources reproduce). Below ACCOUNTED_MIN no modelled source
explains D, and the budget says so, with the part it leaves (u_HS - u_all).

The noise floor is the RMS of the difference the sensors' noise alone makes: NS replayed
NOISE_REALISATIONS times with independent white noise at the levels measured in the run, on the
displacement read (the transducer's, the white level of the measured tracking error) and on the
force (the residual's white level, :func:`noise_level`). A difference within NOISE_FLOOR_FACTOR of it is at the noise floor:
whatever the sources reproduce of it is noise, so no source but the force noise itself is named.

A run stopped early (fewer steps recorded than its record has) is budgeted over the steps it
recorded; the budget says how many of how many, and why it stopped when the run recorded that.

Every call into hsio's run and NS machinery is in :func:`load_run` and :func:`replay`.
"""

from __future__ import annotations

import math
import numbers
import textwrap
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hsio.errors import HsioError, RecordError
from hsio.diagnose.threads import one_blas_thread

SOURCES = ("tracking", "force_noise", "specimen")
ACCOUNTED_MIN = 0.5  # a main source is named only when the sources together reproduce this share of D
DOMINANCE = 2.0  # ... and the largest share is this many times the next and at least 1 / DOMINANCE of A
NOISE_REALISATIONS = 8  # replays with independent noise that set the noise floor
NOISE_FLOOR_FACTOR = 1.5  # a difference within this factor of the noise floor is at it (as residual.FLOOR_FACTOR)
NOISE_SEED = 16  # the realisations are the same at every call
TITLES = {"tracking": "actuator tracking error", "force_noise": "force measurement noise",
          "specimen": "specimen-model mismatch", "rest": "integrator and interaction (the rest)"}


@dataclass
class RunData:
    """What the budget needs of a run, in arrays (step 0 is the initial state)."""

    source: str
    structure: object  # hsio.structures.Structure
    ground: object  # hsio.ground_motion.GroundMotion, up to the last recorded step
    alpha: float
    correction: bool  # the measured force corrected to the target displacement
    t: np.ndarray
    u_hs: np.ndarray  # steps x DOF
    u_ns: np.ndarray
    targets: np.ndarray  # steps x actuators
    displacement: np.ndarray
    force: np.ndarray
    steps_planned: int = 0  # the steps of the run's record (more than recorded: stopped early)
    stop_reason: str | None = None  # why the run stopped, as it recorded it


def load_run(run_dir: str | Path) -> RunData:
    """Read run.sqlite with the structure, record and integrator it was run with."""
    from hsio.config import from_dict
    from hsio.experiment import excitation
    from hsio.recording import Run, column
    from hsio.runner import build_record, load_run_structure
    from hsio.safety.inputs import ground_fingerprint
    from hsio.structures import channel_names

    path = Path(run_dir) / "run.sqlite"
    try:
        run = Run(path)
    except FileNotFoundError:
        raise RecordError(f"{run_dir}: no run.sqlite (give the folder `hsio run` wrote)") from None
    except Exception as exc:
        raise RecordError(f"{path}: not an hsio recording: {exc}") from None
    config = from_dict(run.meta.get("config", {}), str(path), replay=True)
    if config["integrator"]["method"] != "alpha_os":
        raise RecordError(f"{path}: the error budget replays alpha_os runs; this one used {config['integrator']['method']!r}")
    _same_inputs(run, config, path)
    structure = load_run_structure(config)
    several = [e for e in structure.experimental if len(e.basic_dofs) != 1]
    if several:
        e = several[0]
        raise RecordError(f"{path}: the error budget replays elements on one basic DOF each; element {e.name!r} "
                          f"has {len(e.basic_dofs)} ({', '.join(structure.dof_names[d] for d in e.basic_dofs)})")
    ground = build_record(config, structure, replay=True)
    recorded = run.meta.get("ground_motion_sha256")
    if recorded is not None and ground_fingerprint(ground) != recorded:
        raise RecordError(f"{path}: the ground motion built from the run's configuration ({ground.name}) is not the one "
                          f"the run ran ({run.meta.get('record', '?')}; the sha256 of their samples differ): the replays "
                          "would budget another test")
    planned = len(excitation(structure, ground)[0]) - 1
    steps = run.steps
    if steps.get("step") is None or steps["step"].size < 20:
        n = 0 if steps.get("step") is None else steps["step"].size
        why = run.stop_reason()
        raise RecordError(f"{path}: fewer than 20 recorded steps ({n} of {planned} planned"
                          f"{'; ' + why if why else ''})")

    def rows(prefix, names):
        return np.vstack([np.zeros(len(names)), np.column_stack([run.steps[column(prefix, n)] for n in names])])

    dofs, acts = run.dof_names, run.actuator_names
    if list(acts) != channel_names(structure) or list(dofs) != list(structure.dof_names):
        raise RecordError(f"{path}: the recording names DOFs {dofs} and actuators {acts}, not those of its structure "
                          f"{structure.name} ({list(structure.dof_names)}, {channel_names(structure)})")
    u_hs = rows("u", dofs)
    if run.ns and run.ns.get("step") is not None and run.ns["step"].size:
        u_ns = np.column_stack([run.ns[column("u", n)] for n in dofs])[: u_hs.shape[0]]
    else:
        u_ns = None
    t = np.r_[0.0, steps["time_s"]]
    if t.size - 1 < planned:  # stopped early: the replays need the record up to the last recorded step
        ground = ground.truncated(min(t[-1] + 2 * max(ground.dt, structure.dt), ground.duration_s))
    data = RunData(str(path), structure, ground, config["integrator"]["alpha"],
                   bool(config["test"]["measured_displacement_correction"]), t, u_hs, u_ns, rows("target", acts),
                   rows("disp", acts), rows("force", acts), planned, run.stop_reason())
    if data.u_ns is None or data.u_ns.shape != u_hs.shape:
        data.u_ns = replay(data, structure_models(structure))
    return data


def _same_inputs(run, config, path: Path) -> None:
    """The structure and record files the replays read again are those the run began with (their
    SHA-256 in meta ``inputs``), else a RecordError naming each that changed or is missing: a file
    edited since the run would budget another test."""
    from hsio.safety.inputs import compare_inputs

    read_again = [e for e in run.meta.get("inputs") or [] if str(e.get("what", "")).startswith(("[structure]", "[record]"))]
    changed, _ = compare_inputs(read_again, config)
    if changed:
        raise RecordError(f"{path}: the budget replays the run's structure and record, but input files differ from "
                          "those the run began with:\n  " + "\n  ".join(changed) + "\nrestore them as they were")


class _Replay:
    """An experimental site (hsio.sites.ExperimentalSite) whose elements are specimen models,
    with the run's measured errors put in: each trial lands ``tracking_error`` short of its
    target, the displacement it reads carries ``transducer_noise`` (d_m = d - e - n) and the force
    it reads ``force_noise``."""

    late_steps = 0
    lab_time_s = None

    def __init__(self, data: RunData, specimens, tracking_error=None, force_noise=None, transducer_noise=None):
        self.data, self.specimens = data, specimens
        self.error, self.noise, self.transducer = tracking_error, force_noise, transducer_noise
        self.n_elements = len(specimens)
        self.step = 0
        self._daq = None

    def committed(self):
        return np.zeros(self.n_elements), np.zeros(self.n_elements)

    def set_modes(self, modes):
        return []

    def set_trial(self, commands, modes) -> None:
        from hsio.sites import Daq

        self.step += 1
        k = min(self.step, self.data.t.size - 1)
        d = np.asarray(commands, dtype=float)
        stands = d - self.error[k] if self.error is not None else d
        d_m = stands - self.transducer[k] if self.transducer is not None else stands
        F = np.array([s.force(x, self.data.structure.dt) for s, x in zip(self.specimens, stands)])
        if self.noise is not None:
            F = F + self.noise[k]
        self._daq = Daq(u=d_m, R=F, k=np.full(self.n_elements, np.nan), targets=d.copy(), commands=d.copy())

    def get_daq(self):
        return self._daq

    def commit(self) -> None:
        pass

    def take_samples(self):
        return None

    def hold(self) -> None:
        pass

    def close(self) -> None:
        pass


def replay(data: RunData, specimens, tracking_error=None, force_noise=None, transducer_noise=None) -> np.ndarray:
    """NS of the run's structure and record with ``specimens`` in place of the experimental
    elements, and the measured errors put in (displacement history, steps x DOF)."""
    from hsio.api import simulate

    for s in specimens:
        s.revert_to_start()
    site = _Replay(data, specimens, tracking_error, force_noise, transducer_noise)
    result = simulate(data.structure, data.ground, site, "alpha_os",
                      data.alpha, correct_measured_displacement=data.correction)
    n = min(result.u.shape[0], data.u_hs.shape[0])
    if result.stopped:
        raise HsioError(f"{data.source}: the replay stopped: {result.stopped}")
    return result.u[:n]


# -- the budget -----------------------------------------------------------------------------------

def _rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if np.size(x) else 0.0


class _QuasiStatic:
    """A structure's specimen model evaluated as NS evaluates it: with no move time, so that a
    rate-dependent model (a dashpot, friction, inertia) gives its quasi-static force, whatever
    time step the replay passes."""

    def __init__(self, inner):
        self.inner = inner

    @property
    def initial_stiffness(self) -> float:
        return self.inner.initial_stiffness

    def trial(self, u, dt=0.0):
        return self.inner.trial(u)

    def commit(self):
        self.inner.commit()

    def revert_to_start(self):
        self.inner.revert_to_start()

    def force(self, u, dt=0.0):
        return self.inner.force(u)


def structure_models(structure) -> list:
    """The structure's specimen models, one per experimental element, as NS evaluates them."""
    return [_QuasiStatic(e.model()) for e in structure.experimental]


def _path_force(specimen, d: np.ndarray, dt: float) -> np.ndarray:
    specimen.revert_to_start()
    out = np.array([specimen.force(x, dt) for x in d.tolist()])
    specimen.revert_to_start()
    return out


def specimen_models(data: RunData) -> tuple[list, list[dict]]:
    """Per actuator, the specimen model that best predicts its measured force on the last 20 %
    of the steps: the diagnosed model or the structure's model scaled to the measured force, each
    fitted on the first 80 %; or the structure's model with its parameters refitted
    (:func:`_refitted`) when it predicts the last 20 % SPECIMEN_MARGIN times better than both
    (with every parameter free it would otherwise be taken for fitting the force's noise). The
    structure's own model stays when none predicts that force SPECIMEN_MARGIN times better than
    it: a scale of 0.999 fitted to a noisy force is the noise, not a mismatch, and its replay
    would put a spurious share in the budget."""
    from hsio.diagnose.specimen_fit import diagnose_specimen
    from hsio.diagnose.specimen_record import SpecimenRecord
    from hsio.specimens import Diagnosed, make_specimen

    dt = data.structure.dt
    models, notes = [], []
    for j, element in enumerate(data.structure.experimental):
        d, f = data.displacement[:, j], data.force[:, j]
        n_fit = int(0.8 * d.size)
        base = _path_force(_QuasiStatic(element.model()), d, dt)
        scale = float(np.dot(base[:n_fit], f[:n_fit]) / max(np.dot(base[:n_fit], base[:n_fit]), 1e-300))
        scaled = _scaled(_QuasiStatic(element.model()), scale)
        options = [("structure's model scaled by %.3f" % scale, scaled, {"scale": scale})]
        try:
            diag = diagnose_specimen(SpecimenRecord(f"{data.source}#{element.name}", dt, d, f))
            from hsio.diagnose.specimen_fit import specimen_table

            table = {k: v for k, v in specimen_table(diag.extended).items() if k != "kind"}
            options.append((f"diagnosed: {diag.extended.name} (cause {diag.cause})", Diagnosed(**table),
                            {"cause": diag.cause, "params": table}))
        except (HsioError, ValueError):
            pass
        own = _rms(f[n_fit:] - base[n_fit:])
        scored = []
        for name, model, info in options:
            pred = _path_force(model, d, dt)
            scored.append((_rms(f[n_fit:] - pred[n_fit:]), name, model, info))
        err, name, model, info = min(scored, key=lambda s: s[0])
        table = _refitted(element.model(), d, f, n_fit, dt)
        if table is not None:  # taken only when clearly better: with all its parameters free it also fits noise
            model_r = _QuasiStatic(make_specimen(table))
            err_r = _rms(f[n_fit:] - _path_force(model_r, d, dt)[n_fit:])
            if SPECIMEN_MARGIN * err_r < err:
                err, name, model, info = err_r, f"structure's model refitted ({table['kind']})", model_r, {"params": table}
        if not SPECIMEN_MARGIN * err < own:  # no replacement clearly better: the gain would be the force's noise
            name = f"structure's own model (no other predicts its force {SPECIMEN_MARGIN:g} times better)"
            err, model, info = own, _QuasiStatic(element.model()), {}
        models.append(model)
        notes.append({"element": element.name, "model": name, "rms_force_kN": err,
                      "rms_force_structure_model_kN": own, **info})
    return models, notes


SPECIMEN_MARGIN = 1.1  # the refitted model replaces the others only when it predicts the force this much better
REFIT_RANGE = math.log(4.0)  # a refitted parameter stays within a factor of 4 of the structure's value
REFIT_EVALS = 60  # force-path evaluations per refitted parameter, at most


def _refitted(model, d: np.ndarray, f: np.ndarray, n_fit: int, dt: float) -> dict | None:
    """The structure's own specimen model with each of its positive parameters refitted (within a
    factor of 4) to the measured force on the first ``n_fit`` steps, by least squares on the force
    along the measured path: a specimen that differs from its model in shape, not only in scale
    (other pinching, other hardening). Returns the refitted table, or None when the model has no
    parameter to refit or cannot be rebuilt."""
    from scipy import optimize

    from hsio.specimens import make_specimen, specimen_spec

    try:
        spec = specimen_spec(model)
    except Exception:
        return None
    names = [k for k, v in spec.items() if k != "kind" and isinstance(v, numbers.Real) and not isinstance(v, bool)
             and math.isfinite(v) and v > 0]
    if not names or n_fit < 2 * len(names):
        return None
    p0 = np.array([float(spec[k]) for k in names])

    def table(x):
        return {**spec, **dict(zip(names, (p0 * np.exp(x)).tolist()))}

    def residual(x):
        try:
            pred = _path_force(_QuasiStatic(make_specimen(table(x))), d[:n_fit], dt)
        except (HsioError, ValueError, ArithmeticError):
            return np.full(n_fit, 1e6)
        return np.where(np.isfinite(pred), pred - f[:n_fit], 1e6)

    try:
        sol = optimize.least_squares(residual, np.zeros(len(names)), bounds=(-REFIT_RANGE, REFIT_RANGE),
                                     diff_step=1e-3, max_nfev=REFIT_EVALS * len(names))
    except (ValueError, ArithmeticError):
        return None
    return table(sol.x)


class _Scaled:
    """A specimen whose force is ``scale`` times another's (a stiffer or weaker copy)."""

    def __init__(self, inner, scale: float):
        self.inner, self.scale = inner, scale

    @property
    def initial_stiffness(self) -> float:
        return self.scale * self.inner.initial_stiffness

    def trial(self, u, dt=0.0):
        return self.scale * self.inner.trial(u, dt)

    def commit(self):
        self.inner.commit()

    def revert_to_start(self):
        self.inner.revert_to_start()

    def force(self, u, dt=0.0):
        return self.scale * self.inner.force(u, dt)


def _scaled(specimen, scale: float):
    return _Scaled(specimen, scale)


NOISE_HIGH_BAND = 0.5  # the noise's level is read above this fraction of the Nyquist frequency
NOISE_SMOOTHING_BINS = 9  # the residual's spectrum is averaged over this many neighbouring bins


def noise_level(r: np.ndarray) -> float:
    """The white level S_0 of a residual's periodogram |R_k|^2, read in its high band (above
    NOISE_HIGH_BAND of the Nyquist frequency, where the response has no power): the median of
    |R_k|^2 there over ln 2 (a white noise's |R_k|^2 is S_0 times an exponential variable, whose
    median is ln 2). The noise's standard deviation per sample is sqrt(S_0 / N)."""
    P = np.abs(np.fft.rfft(r)) ** 2
    high = P[int(NOISE_HIGH_BAND * (P.size - 1)):]
    return float(np.median(high) / np.log(2.0)) if high.size else 0.0


def noise_estimate(r: np.ndarray) -> tuple[np.ndarray, float]:
    """The noise in a force residual r = s + n, over the whole band, and its standard deviation.

    The noise is taken as white at the level S_0 of :func:`noise_level`, the rest s as what the
    specimen model misses. Per frequency bin the noise's estimate is the Wiener one,
    N_k = H_k R_k with H_k = min(1, S_0 / S_r,k), S_r,k the periodogram averaged over
    NOISE_SMOOTHING_BINS bins: where the residual is at the white level (noise alone, also
    within the structure's band) all of it is noise; where it rises above (a model mismatch)
    only the white level's part is."""
    r = np.asarray(r, dtype=float)
    if r.size < 4:
        return np.zeros_like(r), 0.0
    R = np.fft.rfft(r)
    P = np.abs(R) ** 2
    S0 = noise_level(r)
    w = min(NOISE_SMOOTHING_BINS, 2 * ((P.size - 1) // 2) + 1)
    smooth = np.convolve(np.pad(P, w // 2, mode="reflect"), np.ones(w) / w, mode="valid") if w > 1 else P
    H = np.minimum(1.0, S0 / np.maximum(smooth, 1e-300))
    return np.fft.irfft(H * R, r.size), float(np.sqrt(S0 / r.size))


def tracking_parts(data: RunData) -> tuple[np.ndarray, np.ndarray]:
    """The measured tracking error e = target - d_m split per actuator into its white part
    (:func:`noise_estimate`), the transducer's noise: -n with d_m = d_true + n, and the rest,
    e + n = target - d_true, how far the rod really stood from its target."""
    error = data.targets - data.displacement
    noise = np.column_stack([noise_estimate(error[:, j])[0] for j in range(error.shape[1])]) if error.size else error
    return error - noise, noise


def force_noise(data: RunData, models, transducer=None) -> tuple[np.ndarray, list[dict]]:
    """The measured force's noise per actuator (:func:`noise_estimate` of the model's residual on
    the measured path, less the ``transducer`` noise: where the specimen stood), and per actuator
    its standard deviation and the estimate's RMS."""
    dt = data.structure.dt
    noise = np.zeros_like(data.force)
    notes = []
    path = data.displacement + transducer if transducer is not None else data.displacement
    for j, model in enumerate(models):
        r = data.force[:, j] - _path_force(model, path[:, j], dt)
        noise[:, j], sigma = noise_estimate(r)
        notes.append({"element": data.structure.experimental[j].name, "sigma_kN": sigma,
                      "rms_estimate_kN": _rms(noise[:, j]), "rms_residual_kN": _rms(r)})
    return noise, notes


def white_sigma(x: np.ndarray) -> float:
    """The standard deviation per sample of the white part of ``x`` (:func:`noise_level`)."""
    return float(np.sqrt(noise_level(x) / x.size)) if x.size else 0.0


def noise_floor(data: RunData, force_sigma: list[float]) -> dict:
    """The RMS difference from NS that the sensors' noise alone makes: NS replayed
    NOISE_REALISATIONS times with independent white noise on the displacement read (each
    actuator's transducer, its white level in the measured tracking error) and on the force
    (``force_sigma``, kN per step), the RMS over the realisations."""
    error = data.targets - data.displacement
    transducer = [white_sigma(error[:, j]) for j in range(error.shape[1])]
    rng = np.random.default_rng(NOISE_SEED)
    models = structure_models(data.structure)
    squares = []
    for _ in range(NOISE_REALISATIONS):
        e = rng.normal(0.0, 1.0, error.shape) * np.array(transducer)
        f = rng.normal(0.0, 1.0, data.force.shape) * np.array(force_sigma)
        u = replay(data, models, force_noise=f, transducer_noise=e)
        m = min(u.shape[0], data.u_ns.shape[0])
        squares.append(float(np.mean(np.square(u[:m] - data.u_ns[:m]))))
    return {"rms_mm": float(np.sqrt(np.mean(squares))), "factor": NOISE_FLOOR_FACTOR, "realisations": NOISE_REALISATIONS,
            "transducer_sigma_mm": transducer, "force_sigma_kN": list(map(float, force_sigma))}


@dataclass
class Budget:
    source: str
    t: np.ndarray
    u_hs: np.ndarray
    u_ns: np.ndarray
    replays: dict  # source -> u history with that source alone
    u_all: np.ndarray
    specimen_notes: list = field(default_factory=list)
    steps_planned: int = 0  # 0: not known (taken as the steps recorded)
    stop_reason: str | None = None
    noise_notes: list = field(default_factory=list)
    floor: dict | None = None  # :func:`noise_floor` (None: not estimated)

    @property
    def at_noise_floor(self) -> bool:
        """The difference is within NOISE_FLOOR_FACTOR of what the sensors' noise alone makes."""
        return bool(self.floor) and _rms(self.difference) <= self.floor["factor"] * self.floor["rms_mm"]

    @property
    def difference(self) -> np.ndarray:
        return self.u_hs - self.u_ns

    def share(self, u: np.ndarray) -> float:
        d = _rms(self.difference)
        return 1.0 - _rms(self.u_hs - u) / d if d > 0 else 0.0

    @property
    def accounted(self) -> float:
        return self.share(self.u_all)

    @property
    def ranked(self) -> list[tuple[str, float]]:
        """The sources by share, largest first."""
        return sorted(((k, self.share(u)) for k, u in self.replays.items()), key=lambda x: -x[1])

    @property
    def verdict(self) -> str:
        """``main_source`` (one source carries the difference), ``together`` (the sources account
        for it, none alone), ``unexplained`` (they account for less than ACCOUNTED_MIN of it),
        ``noise_floor`` (the difference is no larger than the sensors' noise makes, and the force
        noise is not the main source) or ``no_difference`` (HS and NS agree: nothing to budget)."""
        if _rms(self.difference) == 0:
            return "no_difference"
        verdict = self._attribution()
        if self.at_noise_floor and not (verdict == "main_source" and self.ranked[0][0] == "force_noise"):
            return "noise_floor"
        return verdict

    def _attribution(self) -> str:
        a = self.accounted
        if not a >= ACCOUNTED_MIN:
            return "unexplained"
        (_, s1), rest = self.ranked[0], self.ranked[1:]
        s2 = max([s for _, s in rest] + [0.0])
        return "main_source" if s1 >= DOMINANCE * s2 and s1 >= a / DOMINANCE else "together"

    @property
    def main_source(self) -> str | None:
        """The source named as the main one, None when the rule above names none."""
        return self.ranked[0][0] if self.verdict == "main_source" else None

    @property
    def steps_recorded(self) -> int:
        return self.t.size - 1

    @property
    def stopped_early(self) -> bool:
        return self.steps_recorded < self.steps_planned

    def run_json(self) -> dict:
        return {"steps_recorded": self.steps_recorded, "steps_planned": self.steps_planned or self.steps_recorded,
                "stopped_early": self.stopped_early, "stop_reason": self.stop_reason}

    def run_line(self) -> str:
        planned = self.steps_planned or self.steps_recorded
        if self.stopped_early:
            line = (f"run stopped early: {self.steps_recorded} of {planned} planned steps recorded; "
                    f"the budget covers these")
        else:
            line = f"run complete: {self.steps_recorded} of {planned} planned steps recorded"
        if self.stop_reason:
            line += f"\nstop recorded: {self.stop_reason}"
        elif self.stopped_early:
            line += "\nstop recorded: none (the run did not record why it stopped)"
        return line

    def unexplained(self) -> dict:
        rest = self.u_hs - self.u_all
        return {"rms_mm": _rms(rest), "peak_mm": float(np.max(np.abs(rest))), "share": 1.0 - self.accounted}

    def conclusion(self) -> str:
        a, verdict = self.accounted, self.verdict
        (top, s1), rest = self.ranked[0], self.ranked[1:]
        if verdict == "no_difference":
            return "HS and NS agree at every recorded step: there is no difference to budget"
        if verdict == "noise_floor":
            return (f"the difference is at the noise floor: HS - NS RMS {_rms(self.difference):.4f} mm, within "
                    f"{self.floor['factor']:g} times the {self.floor['rms_mm']:.4f} mm the sensors' noise alone makes "
                    f"(NS replayed with {self.floor['realisations']} realisations of white noise at the levels measured in "
                    f"the run); no source is named beyond the noise (all sources together account for {100 * a:.1f} % "
                    "of it)")
        if verdict == "main_source":
            floor = (f" (the difference is at the noise floor, {self.floor['rms_mm']:.4f} mm)"
                     if self.at_noise_floor else "")
            return f"all sources together account for {100 * a:.1f} % of the difference; main source: {TITLES[top]}{floor}"
        if verdict == "together":
            nxt, s2 = rest[0] if rest else (None, 0.0)
            why = (f"none alone reproduces any of it (the largest share, {TITLES[top]}, is {100 * s1:.1f} %): they "
                   f"act through their interaction" if s1 <= 0 else
                   f"the largest, {TITLES[top]} ({100 * s1:.1f} %), is under {DOMINANCE:g} times the next, "
                   f"{TITLES[nxt]} ({100 * s2:.1f} %)" if s1 < DOMINANCE * max(s2, 0.0) else
                   f"the largest, {TITLES[top]} ({100 * s1:.1f} %), reproduces under 1/{DOMINANCE:g} of what they "
                   f"do together (they act through their interaction)")
            return (f"all sources together account for {100 * a:.1f} % of the difference; none of them alone is the "
                    f"main source: {why}")
        u = self.unexplained()
        sign = " (negative: with every source put in, the replay is further from HS than NS is)" if a < 0 else ""
        return (f"no modelled source explains the difference: all sources together account for {100 * a:.1f} % of "
                f"it{sign}, under the {100 * ACCOUNTED_MIN:.0f} % needed to name a main source; what they leave "
                f"(the integrator, their interaction or an effect none of them models): RMS {u['rms_mm']:.4f} mm, "
                f"peak {u['peak_mm']:.4f} mm, {100 * u['share']:.1f} % of the difference")

    def rows(self) -> list[dict]:
        out = []
        for s, u in self.replays.items():
            out.append({"source": s, "title": TITLES[s], "rms_mm": _rms(u - self.u_ns), "peak_mm": float(np.max(np.abs(u - self.u_ns))),
                        "share": self.share(u)})
        rest = self.u_hs - self.u_all
        out.append({"source": "rest", "title": TITLES["rest"], "rms_mm": _rms(rest), "peak_mm": float(np.max(np.abs(rest))),
                    "share": 1.0 - self.accounted})
        return out

    def to_json(self) -> dict:
        return {"source": self.source, "rms_difference_mm": _rms(self.difference),
                "peak_difference_mm": float(np.max(np.abs(self.difference))), "sources": self.rows(),
                "accounted": self.accounted, "main_source": self.main_source, "verdict": self.verdict,
                "conclusion": self.conclusion(), "unexplained": self.unexplained(),
                "rule": {"accounted_min": ACCOUNTED_MIN, "dominance": DOMINANCE}, "run": self.run_json(),
                "noise_floor": {**self.floor, "at_floor": self.at_noise_floor} if self.floor else None,
                "specimen_models": self.specimen_notes, "force_noise": self.noise_notes,
                "method": "NS replayed with one measured source at a time; share = 1 - RMS(HS - replay) / RMS(HS - NS)"}

    def table(self) -> str:
        lines = [f"error budget of {self.source}: HS - NS RMS {_rms(self.difference):.4f} mm, peak "
                 f"{np.max(np.abs(self.difference)):.4f} mm", self.run_line(), "",
                 f"{'source':<40} {'RMS (mm)':>10} {'peak (mm)':>10} {'share':>8}"]
        for r in self.rows():
            lines.append(f"{r['title']:<40} {r['rms_mm']:10.4f} {r['peak_mm']:10.4f} {100 * r['share']:7.1f}%")
        lines += ["", textwrap.fill(self.conclusion(), 100)]
        return "\n".join(lines)


@one_blas_thread
def error_budget(run_dir: str | Path) -> Budget:
    data = load_run(run_dir)
    n = data.u_hs.shape[0]
    models, notes = specimen_models(data)
    error, transducer = tracking_parts(data)
    noise, noise_notes = force_noise(data, models, transducer)
    replays = {"tracking": replay(data, structure_models(data.structure), tracking_error=error),
               "force_noise": replay(data, structure_models(data.structure), force_noise=noise, transducer_noise=transducer),
               "specimen": replay(data, models)}
    u_all = replay(data, models, tracking_error=error, force_noise=noise, transducer_noise=transducer)
    floor = noise_floor(data, [n["sigma_kN"] for n in noise_notes])
    m = min(n, data.u_ns.shape[0], u_all.shape[0], *(u.shape[0] for u in replays.values()))
    return Budget(data.source, data.t[:m], data.u_hs[:m], data.u_ns[:m], {k: u[:m] for k, u in replays.items()}, u_all[:m], notes,
                  data.steps_planned, data.stop_reason, noise_notes, floor)


def write_budget(b: Budget, out_dir: str | Path) -> dict:
    import json

    from hsio.diagnose.plotting import figure, label, save

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    fig, axes = figure(2, 1, (11, 6.5), sharex=True)
    dof = int(np.argmax(np.max(np.abs(b.difference), axis=0)))
    axes[0].plot(b.t, b.difference[:, dof], color="k", lw=1.4, label="HS - NS")
    for i, (s, u) in enumerate(b.replays.items()):
        axes[0].plot(b.t, (u - b.u_ns)[:, dof], lw=0.9, color=f"C{i}", label=TITLES[s])
    axes[0].plot(b.t, (b.u_all - b.u_ns)[:, dof], lw=0.9, ls="--", color="C3", label="all sources")
    if b.floor:
        for sign in (1, -1):
            axes[0].axhline(sign * b.floor["rms_mm"], color="0.6", lw=0.8, ls=":", label="noise floor (RMS)" if sign > 0 else None)
    label(axes[0], None, "displacement difference (mm)")
    axes[1].plot(b.t, (b.u_hs - b.u_all)[:, dof], color="0.4", lw=0.8, label=TITLES["rest"])
    label(axes[1], "time (s)", "unaccounted (mm)")
    named = (f"main source {TITLES[b.main_source]}" if b.main_source else
             "at the noise floor" if b.verdict == "noise_floor" else "no main source named")
    early = f" (stopped early: {b.steps_recorded} of {b.steps_planned} steps)" if b.stopped_early else ""
    save(fig, out / "budget.png", f"Error budget: {100 * b.accounted:.1f} % of HS - NS accounted; {named}{early}")
    (out / "budget.md").write_text("# Error budget\n\n```\n" + b.table() + "\n```\n", encoding="utf-8")
    (out / "budget.json").write_text(json.dumps(b.to_json(), indent=2), encoding="utf-8")
    return {"plot": str(out / "budget.png"), "text": str(out / "budget.md"), "json": str(out / "budget.json")}
