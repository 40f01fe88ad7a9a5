"""Cases x controllers x plants: J1-J9 of RTHS runs, nominal and over perturbed plants."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from hsio.rths import benchmark, controllers, criteria, loop, plant as plant_mod

J_NAMES = [f"J{i}" for i in range(1, 10)]


@dataclass
class RunResult:
    case: int
    controller: str
    J: list[float]
    seconds: float  # wall time of the loop
    simulated_s: float
    peak_force_N: float
    peak_stroke_mm: float
    peak_velocity_mm_s: float
    plant: dict = field(default_factory=dict)

    @property
    def real_time_factor(self) -> float:
        return self.simulated_s / self.seconds if self.seconds > 0 else float("inf")


def run_one(bm: benchmark.Benchmark, case: int, controller: str, plant: plant_mod.PlantParameters,
            noise_seed=0, use_numba: bool | None = None, duration: float | None = None,
            ag: np.ndarray | None = None) -> RunResult:
    fs = benchmark.FS
    if ag is None:
        ag = benchmark.ground_motion(bm, duration)
    cs = benchmark.case(bm, case)
    sub = benchmark.numerical_substructure(cs)
    ref_case = cs.with_specimen_stiffness(plant.ke)
    x_ref = benchmark.reference_response(ref_case.M, ref_case.C, ref_case.K, ag)
    stage = controllers.make(controller, fs, plant_mod.nominal(bm.data))
    loop.run(stage, plant, sub, ag[:2], fs, noise_seed, use_numba)  # numba compiles here, not on the clock
    t0 = time.perf_counter()
    r = loop.run(stage, plant, sub, ag, fs, noise_seed, use_numba)
    seconds = time.perf_counter() - t0
    J = criteria.j1_to_j9(r.x_t, r.x_m, r.floors, x_ref, fs)
    vel = np.diff(r.x) * fs
    return RunResult(case, controller, J, seconds, ag.size / fs, float(np.max(np.abs(r.force))),
                     1e3 * float(np.max(np.abs(r.x))), 1e3 * float(np.max(np.abs(vel))),
                     {k: getattr(plant, k) for k in plant_mod.UNCERTAIN})


def limits_reached(row: dict, bm_data: dict) -> list[str]:
    """The benchmark's constraints a run reached: the actuator force held at its saturation, a
    stroke or a velocity beyond the benchmark's limits (those are reported, not enforced)."""
    c = bm_data.get("constraints", {})
    out = []
    if row["peak_force_N"] >= float(c.get("max_force_N", float("inf"))):
        out.append(f"the actuator force saturated at {row['peak_force_N'] / 1e3:g} kN")
    for key, limit, what in (("peak_stroke_mm", "stroke_mm", "stroke"), ("peak_velocity_mm_s", "max_velocity_mm_s", "velocity")):
        try:
            bound = float(c[limit])
        except (KeyError, TypeError, ValueError):
            continue
        if row[key] > bound:
            unit = "mm" if what == "stroke" else "mm/s"
            out.append(f"{what} {row[key]:.4g} {unit} beyond the benchmark's {bound:g} {unit}")
    return out


def summary(results: list[RunResult]) -> dict:
    """Mean and worst of J1-J9 over runs (worst: the largest; for J1 the largest |J1|)."""
    J = np.array([r.J for r in results])
    worst = J.max(axis=0)
    worst[0] = J[np.argmax(np.abs(J[:, 0])), 0]
    return {"mean": J.mean(axis=0).tolist(), "worst": worst.tolist(), "runs": len(results)}


def evaluate(bm: benchmark.Benchmark, case: int, controller: str, perturbed: int = 0, seed: int = 0,
             use_numba: bool | None = None, duration: float | None = None) -> dict:
    """J1-J9 on the nominal plant (``perturbed`` = 0) or the mean and worst over ``perturbed``
    plants drawn with ``seed`` (plant k also gets its own sensor-noise stream)."""
    if isinstance(perturbed, bool) or int(perturbed) != perturbed or perturbed < 0:
        raise ValueError(f"perturbed = {perturbed!r}: the number of perturbed plants is a whole number, 0 or more")
    ag = benchmark.ground_motion(bm, duration)
    if perturbed == 0:
        r = run_one(bm, case, controller, plant_mod.nominal(bm.data), 0, use_numba, ag=ag)
        return {"case": case, "controller": controller, "plant": "nominal", "J": r.J,
                "loop_s": r.seconds, "simulated_s": r.simulated_s, "x_real_time": r.real_time_factor,
                "peak_force_N": r.peak_force_N, "peak_stroke_mm": r.peak_stroke_mm,
                "peak_velocity_mm_s": r.peak_velocity_mm_s,
                "limits_reached": limits_reached(vars(r), bm.data)}
    plants = plant_mod.perturbed(bm.data, seed, perturbed)
    runs = [run_one(bm, case, controller, p, [seed, k], use_numba, ag=ag) for k, p in enumerate(plants)]
    out = {"case": case, "controller": controller, "plant": f"perturbed x{perturbed}, seed {seed}", **summary(runs),
           "loop_s": sum(r.seconds for r in runs), "simulated_s": sum(r.simulated_s for r in runs)}
    out["x_real_time"] = out["simulated_s"] / out["loop_s"]
    out["peak_force_N"] = max(r.peak_force_N for r in runs)
    out["peak_stroke_mm"] = max(r.peak_stroke_mm for r in runs)
    out["peak_velocity_mm_s"] = max(r.peak_velocity_mm_s for r in runs)
    out["limits_reached"] = limits_reached(out, bm.data)
    return out
