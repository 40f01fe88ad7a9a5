"""When mixed control earns its place: DC, FC and mixed against NS over the instruments
(docs/force_control.md, "hsio study mixed"; E&M 2007 section 5).

Two parts:

* a grid over the specimen's stiffness k0 x the transducer's resolution delta_u x the load cell's
  resolution delta_F: a single-DOF frame with a cracking infill (:class:`hsio.specimens.CrackingInfill`
  scaled to k0: cracking at 0.49 mm, the peak at 2.5 mm, the same force ratios), its mass set for a
  natural frequency of 8 Hz, 5 % damping, on the emulated controller; the synthetic record (seed
  :data:`SEED` unless given) is scaled so that the NS peak is about the cracking displacement
  (the infill just cracks);
* the shipped structures (``structure_I``, ``structure_II``, ``structure_II_infill``,
  ``three_storey``) with every method;
* a lab's own run configurations (:func:`configured`): its structure file, record, test rate and
  emulated instruments, with every method.

Each run is HS on the emulator (lockstep) against NS (implicit DC converged, the specimen models),
error = max over time and DOF of |u_HS - u_NS| / peak |u_NS| (``hsio.result.max_error_pct``).
The methods, as :func:`make_method` builds them from the instruments:

* ``implicit_dc``: every element in DC;
* ``force_control``: every element in FC, base displacement from the complementary estimate
  (``fc_blend``);
* ``mixed``: thresholds from the instruments (:meth:`SwitchingRule.from_instruments`), FC only
  while NS predicts every element elastic, the complementary estimate in FC, non-converged FC
  steps finished in DC with a refractory period.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from hsio.config import BOUNDS, DEFAULTS
from hsio.errors import ConfigError
from hsio.integrators import ImplicitMethod, SwitchingRule
from hsio.integrators.mixed import check_ns, instrument_uncertainty
from hsio.structures import Structure, get_structure, sdof

METHODS = ("implicit_dc", "force_control", "mixed")
SEED = 1994  # the study's synthetic record
STRUCTURES = ("structure_I", "structure_II", "structure_II_infill", "three_storey")


@dataclass(frozen=True)
class Recipe:
    """How the methods use the instruments (the defaults of ``hsio study mixed``)."""

    margin: float = 0.03  # c in K_f = c s_F / s_u
    hysteresis: float = 2.0  # K_d = K_f / h
    max_hysteretic_ratio: float = 0.1  # FC only while NS predicts every element elastic (0: no such gate)
    fc_blend: float = 0.01  # lambda of the complementary estimate
    fallback_after: int = 2  # FC commands before a non-converging FC element goes on in DC (below j_max; 0: off)
    refractory_steps: int = 10**9  # an element that failed in FC stays in DC for the rest of the run
    no_fc_at_reversal: bool = True
    j_max: int = 3
    tol_displacement: float = 0.02
    tol_force: float = 0.05
    alpha: float = -0.05

    def __post_init__(self):
        for key, config_key in CONFIG_KEYS.items():
            low, high, _ = BOUNDS[("integrator", config_key)]
            whole = isinstance(DEFAULTS["integrator"][config_key], int)
            value = getattr(self, key)
            kind = int if whole else (int, float)
            if isinstance(value, bool) or not isinstance(value, kind) or not (math.isfinite(value) and low <= value <= high):
                what = f"a whole number in {low}..{high}" if whole else f"a number in [{low:g}, {high:g}]"
                raise ConfigError(f"Recipe: {key} must be {what}, got {value!r}")
        if 0 < self.fallback_after >= self.j_max:
            raise ConfigError(f"Recipe: fallback_after ({self.fallback_after}) must be below j_max ({self.j_max}): "
                              f"after that many FC commands the step's remaining commands go in DC; 0: off")
        alpha = self.alpha
        if isinstance(alpha, bool) or not isinstance(alpha, (int, float)) or not -1.0 / 3.0 <= alpha <= 0.0:
            raise ConfigError(f"Recipe: alpha must be a number in [-0.333333, 0], got {alpha!r}")
        if not isinstance(self.no_fc_at_reversal, bool):
            raise ConfigError(f"Recipe: no_fc_at_reversal must be True or False, got {self.no_fc_at_reversal!r}")


# Each bounded field of Recipe and the [integrator] key of a run configuration whose bounds it takes
# (hsio.config.BOUNDS).
CONFIG_KEYS = {"margin": "switch_margin", "hysteresis": "switch_hysteresis",
               "max_hysteretic_ratio": "switch_max_hysteretic_ratio", "fc_blend": "fc_blend",
               "fallback_after": "fc_fallback_after", "refractory_steps": "refractory_steps", "j_max": "j_max",
               "tol_displacement": "tol_displacement_mm", "tol_force": "tol_force_kN"}


def make_method(structure: Structure, method: str, resolution_mm: float, force_resolution_kN: float,
                recipe: Recipe = Recipe(), noise_mm: float = 0.0, force_noise_kN: float = 0.0,
                ns=None) -> ImplicitMethod:
    """The integrator of ``method`` for ``structure`` with the given instruments; in ``mixed``, no
    element goes to FC where ``ns`` (NS of the same structure and record) predicts one to
    dissipate energy (:meth:`SwitchingRule.elastic_only`)."""
    if not isinstance(structure, Structure):
        raise ConfigError(f"structure must be a Structure, got {structure!r:.80}")
    if method not in METHODS:
        raise ConfigError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    if not isinstance(recipe, Recipe):
        raise ConfigError(f"recipe must be a Recipe (for a table: Recipe(**table)), got {recipe!r:.80}")
    instruments = {"resolution_mm": resolution_mm, "force_resolution_kN": force_resolution_kN, "noise_mm": noise_mm,
                   "force_noise_kN": force_noise_kN}
    for name, value in instruments.items():  # every method reads them (FC's secant rule, eq. 11a)
        if isinstance(value, bool) or not isinstance(value, numbers.Real) or not (math.isfinite(value) and value >= 0):
            raise ConfigError(f"{name} must be a number, zero or positive, got {value!r:.80}")
    if ns is not None:
        check_ns(ns, structure)
    K_EI = [e.K_EI for e in structure.experimental]
    r = recipe
    rule = None
    if method == "mixed":
        rule = SwitchingRule.from_instruments(K_EI, resolution_mm, force_resolution_kN, r.margin, r.hysteresis,
                                              noise_mm, force_noise_kN)
        if r.max_hysteretic_ratio > 0:
            if ns is None:
                raise ConfigError("mixed: give ns= (NS of the same structure and record) for the prediction of "
                                  "which elements stay elastic, or Recipe(max_hysteretic_ratio=0) to let every "
                                  "element go to FC")
            rule = rule.elastic_only(ns, structure, r.max_hysteretic_ratio)
    blend = r.fc_blend if method != "implicit_dc" else 1.0
    extra = {}
    s_u, s_F = instrument_uncertainty(resolution_mm, noise_mm), instrument_uncertainty(force_resolution_kN,
                                                                                       force_noise_kN)
    if method == "force_control" and s_u + s_F > 0:  # the instruments known: FC's secant beyond their noise (eq. 11a)
        extra["secant_uncertainty"] = ((noise_mm, resolution_mm), (force_noise_kN, force_resolution_kN))
    if method == "mixed":
        extra = {**extra, "fallback_after": r.fallback_after, "refractory_steps": r.refractory_steps,
                 "no_fc_at_reversal": r.no_fc_at_reversal}
    return ImplicitMethod(structure.M, structure.C, structure.numerical_assembly().K_linear,
                          structure.experimental_dofs, K_EI, structure.dt, r.alpha, method, rule, structure.dof_names,
                          j_max=r.j_max, tol_displacement=r.tol_displacement, tol_force=r.tol_force, fc_blend=blend,
                          element_refs=structure.experimental_refs, **extra)


@dataclass
class Row:
    case: str
    k0_kN_mm: float
    resolution_mm: float
    force_resolution_kN: float
    method: str
    error_pct: float  # inf when the run stopped (an interlock or a command beyond the limits)
    switches: int
    not_converged_steps: int
    fc_fraction: float  # share of the element-steps run in force control (the steps made)
    ns_peak_mm: float
    stopped: str = ""  # why the run stopped before the end of the record ("": it did not)
    secant_refused: int = 0  # FC estimates of eq. (11) turned away (eq. 11a)


def infill_sdof(k0: float, dt: float = 0.005, f_hz: float = 8.0) -> Structure:
    """The grid's specimen: a single-DOF frame whose infill has initial stiffness ``k0``."""
    s = k0 / 122.6
    spec = {"kind": "cracking_infill", "k0": k0, "F_cr": 60.0 * s, "F_max": 85.0 * s, "u_max": 2.5,
            "F_res": 40.0 * s, "u_res": 10.0, "gamma": 40.0}
    m = k0 / (2 * math.pi * f_hz) ** 2
    return sdof(m=m, k=k0, zeta=0.05, dt=dt, specimen=spec)


def capacity_kN(k0: float) -> float:
    """The grid's actuator capacity: the emulator's 250 kN, or twice the infill's peak strength
    where that is more (a stiff specimen's strength scales with k0, and the study is about the
    instruments, not about an actuator too small for the specimen)."""
    from hsio.emulators.servo import ServoConfig

    return max(ServoConfig().force_limit_kN, 2.0 * infill_sdof(k0).experimental[0].specimen["F_max"])


def run_case(case: str, structure: Structure, ground, methods, resolution_mm: float, force_resolution_kN: float,
             test_rate: float = 10.0, hold_fraction: float = 0.5, recipe: Recipe = Recipe(), ns=None,
             force_noise_kN: float | None = None, emulator: dict | None = None,
             noise_mm: float | None = None, compensation: dict | None = None) -> list[Row]:
    """HS of each method on the emulator with the given instruments (the load cell's noise
    standard deviation equal to its resolution unless given; the transducer's likewise when
    ``noise_mm`` is "resolution", else as given, None: the emulator's default), against NS.

    ``compensation``: a [compensation] table (docs/compensation.md), e.g. ``{"mode": "online"}``:
    feed-forward compensation of the actuators in displacement control, a new stage per run."""
    from hsio.api import dwell_periods, open_site, run_numerical, simulate
    from hsio.compensation.stage import CompensationSettings, CompensationStage
    from hsio.emulators.servo import ServoConfig
    from hsio.experiment import ExperimentStopped
    from hsio.result import max_error_pct
    from hsio.structures import channel_names
    from hsio.secant import SecantEstimator

    if not isinstance(recipe, Recipe):
        raise ConfigError(f"recipe must be a Recipe (for a table: Recipe(**table)), got {recipe!r:.80}")
    if isinstance(methods, str) or not all(isinstance(m, str) and m in METHODS for m in methods):
        raise ConfigError(f"methods must be a list of {', '.join(METHODS)}, got {methods!r:.80}")
    if ns is None:
        ns = run_numerical(structure, ground, "mixed", recipe.alpha)
    peak = float(np.max(np.abs(ns.u)))
    options = {"resolution_mm": resolution_mm, "force_resolution_kN": force_resolution_kN,
               "force_noise_kN": force_resolution_kN if force_noise_kN is None else force_noise_kN, **(emulator or {})}
    if noise_mm is not None:
        options["noise_mm"] = resolution_mm if noise_mm == "resolution" else float(noise_mm)
    k0 = float(max(e.K_EI for e in structure.experimental))
    servo = ServoConfig()
    noise = (float(options.get("noise_mm", servo.noise_mm)), float(options["force_noise_kN"]))
    # the secant averages 16 controller periods, or the whole dwell of a faster test (as hsio run
    # averages where [integrator] secant_n_avg is left out)
    n_avg = min(16, dwell_periods(structure.dt, test_rate, hold_fraction))
    rows = []
    for method in methods:
        integrator = make_method(structure, method, resolution_mm, force_resolution_kN, recipe, *noise, ns=ns)
        stage = None
        if compensation is not None:
            stage = CompensationStage(channel_names(structure), test_rate * structure.dt,
                                      CompensationSettings.from_table(compensation, "study compensation"))
        with open_site(structure, "emulator://", test_rate=test_rate, hold_fraction=hold_fraction, options=options,
                       estimator=SecantEstimator("average", n_avg, 0.1), compensation=stage) as site:
            try:
                hs = simulate(structure, ground, site, integrator=integrator)
            except ExperimentStopped as exc:
                if isinstance(exc.cause, KeyboardInterrupt):  # Ctrl-C stops the study, not this run
                    raise exc.cause from None
                made = exc.result
                rows.append(Row(case, k0, resolution_mm, force_resolution_kN, method, math.inf, len(made.switches),
                                _not_converged(made), _fc_fraction(made), peak, str(exc),
                                sum(made.secant_refused or [])))
                continue
        error, _ = max_error_pct(hs.u, ns.u)
        rows.append(Row(case, k0, resolution_mm, force_resolution_kN, method, float(error), len(hs.switches),
                        _not_converged(hs), _fc_fraction(hs), peak, "", sum(hs.secant_refused or [])))
    return rows


def _fc_fraction(result) -> float:
    """Share of the experimental elements' steps run in FC (NaN when no step was made)."""
    fc = np.asarray(result.force_control[1:], dtype=bool)
    return float(np.mean(fc)) if fc.size else math.nan


def _not_converged(result) -> int:
    return int(np.sum(~np.asarray(result.converged[1:], dtype=bool)))


def grid(stiffnesses=(7.2, 122.6), resolutions=(0.0025, 0.025), force_resolutions=(0.002, 0.02),
         duration_s: float = 2.0, methods=METHODS, recipe: Recipe = Recipe(), progress=None,
         noise_mm=None, seed: int = SEED) -> list[Row]:
    """The grid study: every combination, every method (the synthetic record of ``seed`` scaled to
    just crack the infill; the actuator's capacity :func:`capacity_kN`)."""
    from hsio.api import run_numerical
    from hsio.ground_motion import synthetic_record

    _check_seed(seed)
    for name, values in (("stiffnesses", stiffnesses), ("resolutions", resolutions),
                         ("force_resolutions", force_resolutions)):
        _check_axis(name, values)
    stiffnesses, resolutions, force_resolutions = (list(dict.fromkeys(float(v) for v in axis))  # each value once
                                                   for axis in (stiffnesses, resolutions, force_resolutions))
    rows = []
    for k0 in stiffnesses:
        structure = infill_sdof(float(k0))
        base = synthetic_record(duration_s=duration_s, dt=structure.dt, pga_g=0.1, seed=seed)
        ns = run_numerical(structure, base, "mixed", recipe.alpha)
        scale = 0.49 / max(float(np.max(np.abs(ns.u))), 1e-9)
        ground = synthetic_record(duration_s=duration_s, dt=structure.dt, pga_g=0.1 * scale, seed=seed)
        ns = run_numerical(structure, ground, "mixed", recipe.alpha)
        emulator = {"force_limit_kN": capacity_kN(float(k0))}
        for du in resolutions:
            for dF in force_resolutions:
                rows += run_case("grid", structure, ground, methods, float(du), float(dF), recipe=recipe, ns=ns,
                                 noise_mm=noise_mm, emulator=emulator)
                if progress:
                    progress(rows[-len(methods):])
    return rows


def _check_seed(seed) -> None:
    """A seed of the synthetic record: a whole number from 0 (checked before any run)."""
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ConfigError(f"grid: seed must be a whole number from 0, got {seed!r:.80}")


def _check_axis(name: str, values) -> None:
    """An axis of the grid: a non-empty sequence of positive finite numbers."""
    ok = isinstance(values, (list, tuple, np.ndarray)) and len(values) > 0 and all(
        isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))
        and math.isfinite(v) and v > 0 for v in values)
    if not ok:
        raise ConfigError(f"grid: {name} must be a non-empty list of positive numbers, got {values!r:.80}")


def structures(names=STRUCTURES, duration_s: float = 4.0, resolution_mm: float = 0.025,
               force_resolution_kN: float = 0.01, methods=METHODS, recipe: Recipe = Recipe(),
               pga=None, progress=None) -> list[Row]:
    """The shipped structures with every method (synthetic record, seed 1994)."""
    from hsio.ground_motion import synthetic_record

    default_pga = {"structure_I": 0.6, "structure_II": 0.15, "structure_II_infill": 0.15, "three_storey": 0.3}
    rows = []
    for name in names:
        structure = get_structure(name)
        g = (pga or default_pga).get(name, 0.3)
        ground = synthetic_record(duration_s=duration_s, dt=structure.dt, pga_g=g, seed=1994)
        emulator = {"force_limit_kN": 1000.0} if name == "three_storey" else None  # as examples/run_three_storey.toml
        rows += run_case(name, structure, ground, methods, resolution_mm, force_resolution_kN, recipe=recipe,
                         emulator=emulator)
        if progress:
            progress(rows[-len(methods):])
    return rows


def configured(path, methods=METHODS, recipe: Recipe = Recipe(), progress=None, case: str | None = None) -> list[Row]:
    """A lab's own run configuration (the TOML file of ``hsio run``) with every method: its
    structure (a structure file or a shipped name), its record (scaled and cut as the run would),
    its test rate and hold fraction, and its emulated controller ([emulator], [hardware]
    actuator_model: the instruments, the actuator's lag and limits); [compensation] as the run
    would apply it. The methods are :func:`make_method`'s from the emulated instruments and the
    study's ``recipe``: the configuration's [integrator] table is not read (the study compares the
    methods, not the configuration's one). Lockstep, whatever [hardware] clock says; a
    configuration for real hardware is refused (the study runs on the emulated controller). The
    rows' ``case`` is ``case``, else the file's name."""
    from hsio import config as run_config
    from hsio.diagnose.modelfile import merged_emulator_table
    from hsio.runner import _instrument_values, build_record, load_run_structure

    config = run_config.load(path)
    url = config["hardware"]["url"]
    if not url.startswith("emulator"):
        raise ConfigError(f"{config.source}: [hardware] url = {url!r}: hsio study mixed runs on the emulated "
                          "controller (url = \"emulator://\"); the runs compare the methods, not the rig")
    structure = load_run_structure(config)
    ground = build_record(config, structure)
    emulator = merged_emulator_table(config["hardware"]["actuator_model"], config["emulator"])
    du, dF, su, sF = _instrument_values(DEFAULTS["integrator"], emulator)  # the emulated controller's, as hsio run reads them
    compensation = config["compensation"] if config["compensation"]["mode"] != "off" else None
    try:
        rows = run_case(case or Path(config.source).name, structure, ground, methods, du, dF, config["test"]["rate"],
                        config["test"]["hold_fraction"], recipe, force_noise_kN=sF, noise_mm=su,
                        emulator=dict(emulator), compensation=compensation)
    except ConfigError as exc:
        raise ConfigError(f"{config.source}: {exc}") from None
    if progress:
        progress(rows)
    return rows


def winners(rows: list[Row]) -> dict:
    """Per configuration: the method with the smallest error, and whether mixed is within 20 %
    (relative) or 0.1 percentage point of the better of DC and FC. A run that stopped (error
    infinite) wins nothing: where every method stopped, ``best`` is None, and so is ``mixed_ok``
    where DC, FC and mixed all stopped; a mixed run that stopped where DC or FC finished is not ok."""
    out = {}
    for row in rows:
        out.setdefault((row.case, row.k0_kN_mm, row.resolution_mm, row.force_resolution_kN), {})[row.method] = row
    summary = {}
    for key, by in out.items():
        finished = [r for r in by.values() if math.isfinite(r.error_pct)]
        best = min(finished, key=lambda r: r.error_pct).method if finished else None
        ok = None
        if {"implicit_dc", "force_control", "mixed"} <= set(by):
            ref = min(by["implicit_dc"].error_pct, by["force_control"].error_pct)
            mixed = by["mixed"].error_pct
            if math.isfinite(mixed):
                ok = mixed <= max(1.2 * ref, ref + 0.1)
            elif math.isfinite(ref):
                ok = False
        summary[key] = {"best": best, "mixed_ok": ok}
    return summary


def rows_as_dicts(rows: list[Row]) -> list[dict]:
    return [{k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in asdict(r).items()}
            for r in rows]


def plot(rows: list[Row], path: str) -> None:
    """Error maps: per load-cell resolution, the error of each method over k0 x delta_u, and the
    winner; below them, the error of each method on each structure or run configuration (bars, a
    stopped run marked)."""
    import matplotlib

    import matplotlib.pyplot as plt

    if not rows:
        raise ValueError("no rows to plot: run the grid, the structures or a configuration first")
    grid_rows = [r for r in rows if r.case == "grid"]
    case_rows = [r for r in rows if r.case != "grid"]
    ks = sorted({r.k0_kN_mm for r in grid_rows})
    dus = sorted({r.resolution_mm for r in grid_rows})
    dFs = sorted({r.force_resolution_kN for r in grid_rows})
    columns = len(METHODS) + 1
    fig = plt.figure(figsize=(4 * columns, 3.2 * (len(dFs) + (1 if case_rows else 0))))
    layout = fig.add_gridspec(len(dFs) + (1 if case_rows else 0), columns)
    for i, dF in enumerate(dFs):
        axes = [fig.add_subplot(layout[i, j]) for j in range(columns)]
        errs = {}
        for j, method in enumerate(METHODS):
            E = np.full((len(dus), len(ks)), np.nan)  # NaN: not run; inf: the run stopped
            for r in grid_rows:
                if r.method == method and r.force_resolution_kN == dF:
                    E[dus.index(r.resolution_mm), ks.index(r.k0_kN_mm)] = r.error_pct
            errs[method] = E
            ax = axes[j]
            shown = np.where(np.isfinite(E), np.minimum(E, 1e3), np.nan)  # a stopped run is left blank
            im = ax.imshow(np.log10(np.maximum(shown, 1e-3)), origin="lower", aspect="auto", cmap="viridis")
            fig.colorbar(im, ax=ax, label="log10 error (%)")
            ax.set_title(f"{method}, dF = {dF:g} kN" + (" (blank: stopped)" if np.isinf(E).any() else ""))
        stack = np.stack([np.where(np.isnan(errs[m]), np.inf, errs[m]) for m in METHODS])
        best = np.where(np.isfinite(stack).any(axis=0), np.argmin(stack, axis=0), np.nan)  # none where all stopped
        ax = axes[-1]
        ax.imshow(best, origin="lower", aspect="auto", vmin=0, vmax=2, cmap="Set1")
        ax.set_title(f"winner (0 DC, 1 FC, 2 mixed), dF = {dF:g} kN")
        for a in axes:
            a.set_xticks(range(len(ks)), [f"{k:g}" for k in ks])
            a.set_yticks(range(len(dus)), [f"{d:g}" for d in dus])
            a.set_xlabel("k0 (kN/mm)")
            a.set_ylabel("delta_u (mm)")
    if case_rows:
        _plot_cases(fig.add_subplot(layout[len(dFs), :]), case_rows)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _plot_cases(ax, rows: list[Row]) -> None:
    """Grouped bars: per structure or run configuration, each method's error (log scale); a run
    that stopped is a hatched bar at the top, labelled."""
    cases = list(dict.fromkeys(r.case for r in rows))
    finite = [r.error_pct for r in rows if math.isfinite(r.error_pct) and r.error_pct > 0]
    top = 10 ** math.ceil(math.log10(max(finite))) if finite else 100.0
    width = 0.8 / len(METHODS)
    for j, method in enumerate(METHODS):
        for i, case in enumerate(cases):
            found = [r for r in rows if r.case == case and r.method == method]
            if not found:
                continue
            x = i - 0.4 + (j + 0.5) * width
            error = found[0].error_pct
            if math.isfinite(error):
                ax.bar(x, max(error, 1e-3), width, color=f"C{j}", label=method if i == 0 else None)
                ax.text(x, max(error, 1e-3), f"{error:.3g}", ha="center", va="bottom", fontsize=7)
            else:
                ax.bar(x, top, width, color="none", edgecolor=f"C{j}", hatch="//", label=method if i == 0 else None)
                ax.text(x, top, "stopped", ha="center", va="bottom", fontsize=7, rotation=90)
    ax.set_yscale("log")
    ax.set_xticks(range(len(cases)), cases)
    ax.set_ylabel("HS-vs-NS error (% of the NS peak)")
    ax.set_title("each method on the structures and run configurations")
    ax.legend(fontsize=8)
