"""Where the HS-vs-NS error of the cracking infill comes from (docs/force_control.md, "Where DC's
error after cracking comes from").

structure_II_infill (the infill of test structure II cracks at 0.49 mm), 4 s synthetic records,
lockstep, ramp-hold, implicit DC with online compensation and ``anchor_dc`` (the study's DC),
at TR 10 and TR 40, with the emulator's sensors as configured (a 0.025 mm transducer with
0.01 mm noise, a 0.01 kN load cell with 0.01 kN noise) and with one part made ideal at a time:

* ``reading ideal``: what the host reads of the specimen's displacement is exact; the servo loop
  still closes on the noisy, quantised rod transducer (the rod jitters as before);
* ``loop ideal``: the loop closes on the exact rod position (no jitter); the host reads the noisy
  transducer;
* ``ideal``: both, and an exact load cell.

Then FC alone with ideal instruments (the measured base, ``fc_blend`` 1) and mixed as ``hsio study
mixed`` builds it, at TR 40. The error is max |u_HS - u_NS| / peak |u_NS| over the steps before the
IF storey first passes 0.49 mm in NS, and over the steps after.

The split is made by replacing the emulated controller's sensor model for the run (the bench's
own experiment; the emulator has no such setting).

Run: PYTHONPATH=. python bench/bench_mixed_cracking.py [--quick]   (about 3 min; --quick: 1 record)
"""

from __future__ import annotations

import sys
import time
from contextlib import contextmanager

import numpy as np

import hsio.emulators.servo as servo
from hsio import study_mixed
from hsio.api import open_site, run_numerical, simulate
from hsio.compensation.stage import CompensationSettings, CompensationStage
from hsio.experiment import ExperimentStopped
from hsio.ground_motion import synthetic_record
from hsio.structures import channel_names
from hsio.secant import SecantEstimator
from hsio.structures import get_structure

CRACK_MM = 0.49
RECORDS = [(0.18, 1994), (0.2, 1994), (0.18, 7), (0.25, 7)]
INSTRUMENTS = {"resolution_mm": 0.025, "force_resolution_kN": 0.01, "force_noise_kN": 0.01}
EXACT_LOAD_CELL = {"force_resolution_kN": 0.0, "force_noise_kN": 0.0}


@contextmanager
def sensors(ideal: str | None):
    """The emulated sensors with one part exact: None, "reading", "loop" or "both"."""
    original = servo.ServoController._measure

    def measure(self):
        original(self)
        if ideal in ("reading", "both"):
            self.measured_displacement = self.d_spec
        if ideal in ("loop", "both"):
            self._rod_feedback = self.d_rod

    servo.ServoController._measure = measure
    try:
        yield
    finally:
        servo.ServoController._measure = original


def split_error(hs_u, ns_u, dof: int) -> tuple[float, float | None]:
    peak = float(np.max(np.abs(ns_u)))
    n = min(len(hs_u), len(ns_u))
    e = np.max(np.abs(hs_u[:n] - ns_u[:n]), axis=1) / peak * 100
    cross = np.flatnonzero(np.abs(ns_u[:n, dof]) > CRACK_MM)
    if cross.size == 0:
        return float(e.max()), None
    return float(e[: cross[0]].max()), float(e[cross[0]:].max())


def run(pga: float, seed: int, method: str, test_rate: float, ideal: str | None = None, fc_blend: float | None = None):
    structure = get_structure("structure_II_infill")
    ground = synthetic_record(duration_s=4.0, dt=structure.dt, pga_g=pga, seed=seed)
    ns = run_numerical(structure, ground, "mixed", -0.05)
    # FC allowed before cracking (no NS gate) with K_f = 6, K_d = 3 kN/mm: the thresholds of the
    # figures in docs/force_control.md ("Why mixed only ties DC once the infill cracks")
    recipe = study_mixed.Recipe(margin=7.125, max_hysteretic_ratio=0.0)
    integrator = study_mixed.make_method(structure, method, 0.025, 0.01, recipe, 0.01, 0.01)
    integrator.core.anchor_dc[:] = method != "force_control"
    if method == "force_control":
        integrator.core.reset_at_reversal = True
    if fc_blend is not None:
        integrator.core.fc_blend = fc_blend
    options = {**INSTRUMENTS, **(EXACT_LOAD_CELL if ideal == "both" else {})}
    stage = None
    if method != "force_control":
        stage = CompensationStage(channel_names(structure), test_rate * structure.dt,
                                  CompensationSettings.from_table({"mode": "online"}, "bench"))
    with sensors(ideal), open_site(structure, "emulator://", test_rate=test_rate, hold_fraction=0.5, options=options,
                                   estimator=SecantEstimator("average", 16, 0.1), compensation=stage) as site:
        try:
            hs = simulate(structure, ground, site, integrator=integrator)
        except ExperimentStopped:
            return None, None
    return split_error(hs.u, ns.u, structure.dof_names.index("IF"))


def cell(before, after) -> str:
    if before is None:
        return "stopped"
    return f"{before:.2f} / {after:.2f}" if after is not None else f"{before:.2f} / -"


def main() -> None:
    records = RECORDS[1:2] if "--quick" in sys.argv else RECORDS
    rows = [("DC", "implicit_dc", 10, None, None), ("DC, reading ideal", "implicit_dc", 10, "reading", None),
            ("DC, loop ideal", "implicit_dc", 10, "loop", None), ("DC, ideal", "implicit_dc", 10, "both", None),
            ("DC", "implicit_dc", 40, None, None), ("DC, reading ideal", "implicit_dc", 40, "reading", None),
            ("DC, loop ideal", "implicit_dc", 40, "loop", None), ("DC, ideal", "implicit_dc", 40, "both", None),
            ("FC, ideal, fc_blend 1", "force_control", 40, "both", 1.0), ("mixed", "mixed", 40, None, None)]
    print("structure_II_infill, error % of the NS peak, before / after the infill cracks in NS")
    print(f"{'run':<24} {'TR':>3} " + " ".join(f"{f'{p:g} g, {s}':>16}" for p, s in records) + f" {'s/run':>6}")
    for label, method, tr, ideal, blend in rows:
        t0 = time.perf_counter()
        cells = [cell(*run(p, s, method, tr, ideal, blend)) for p, s in records]
        per = (time.perf_counter() - t0) / len(records)
        print(f"{label:<24} {tr:>3} " + " ".join(f"{c:>16}" for c in cells) + f" {per:>6.1f}", flush=True)


if __name__ == "__main__":
    main()
