"""Iterations per step and wall time per step of implicit FC and DC (docs/method.md sections 3 and 5).

1. The parametric-study SDOF (Menegotto-Pinto, n = 1, step load): numerical, one system at a time.
2. Test structure I (pinched wood wall) on the emulated controller, lockstep, TR = 10:
   implicit DC, FC, mixed (K_f = 1.2 K^EI, K_d = 0.8 K^EI), and alpha-OS, each against its NS
   (the iterated alpha method on the specimen model; alpha-OS against alpha-OS on the model).
3. The fc-vs-dc study as a whole (the time `hsio study fc-vs-dc` takes).
4. Stiff specimens (docs/force_control.md): structure_II_infill with a 0.025 mm transducer and a
   0.01 kN load cell, DC, FC and mixed as `hsio study mixed` builds them (thresholds from the
   instruments, complementary FC base, non-converged FC finished in DC).

Run: PYTHONPATH=. python bench/bench_force_control.py
"""

from __future__ import annotations

import time

import numpy as np

from hsio.emulators.local import open_url
from hsio import study
from hsio.api import run_numerical, simulate
from hsio.clock import LockstepClock
from hsio.control_loop import ControlLoop
from hsio.result import max_error_pct
from hsio.sites import ActuatorSite
from hsio.ground_motion import synthetic_record
from hsio.interfaces import ControlMode
from hsio.secant import SecantEstimator
from hsio.structures import structure_I


def numerical_sdof() -> None:
    print("1. Study SDOF (Menegotto-Pinto n = 1, P = 3 k0 u_y, 5 s), tol 1e-10, j_max 10, one system")
    print(f"{'theta':>6} {'dt':>6} {'mode':>5} {'its/step mean':>14} {'max':>4} {'wall/step (us)':>15}")
    for theta in (0.2, 1.0, 5.0):
        for dt in (0.02, 0.005):
            for mode in (ControlMode.DISPLACEMENT, ControlMode.FORCE):
                t0 = time.perf_counter()
                u, its = study.run_algorithm(np.array([theta]), np.array([0.05]), -0.3, dt, mode)
                wall = time.perf_counter() - t0
                steps = len(u) - 1
                name = "DC" if mode is ControlMode.DISPLACEMENT else "FC"
                print(f"{theta:6.2f} {dt:6.3f} {name:>5} {its[1:].mean():14.2f} {its[1:].max():4d} {wall / steps * 1e6:15.1f}")


def emulated_structure_I(duration_s: float = 4.0, test_rate: float = 10.0) -> None:
    structure = structure_I()
    ground = synthetic_record(duration_s=duration_s, dt=structure.dt, pga_g=0.6, seed=1994)
    ns = run_numerical(structure, ground, "mixed", -0.05)
    print(f"\n2. Structure I on the emulator (lockstep, TR = {test_rate:g}, {duration_s:g} s, peak NS "
          f"{np.max(np.abs(ns.u)):.1f} mm), secant averaged over 16 samples, j_max 3")
    print(f"{'method':>12} {'its/step':>9} {'max':>4} {'FC steps':>9} {'switches':>9} {'wall/step (ms)':>15} "
          f"{'lab time (s)':>13} {'max err vs NS (%)':>18}")
    for method in ("alpha_os", "implicit_dc", "force_control", "mixed"):
        clock = LockstepClock()
        actuators = open_url("emulator://", structure.experimental, clock, {})
        loop = ControlLoop(actuators, clock, structure.dt, test_rate, n_avg=4, keep_samples=True, hold_fraction=0.5)
        t0 = time.perf_counter()
        if method == "alpha_os":
            sub = ActuatorSite(loop)
            hs = simulate(structure, ground, sub, "alpha_os", -0.05)
            its, fc, switches = np.ones(1), 0.0, 0
            reference = run_numerical(structure, ground, "alpha_os", -0.05)  # its own NS
        else:
            sub = ActuatorSite(loop, SecantEstimator("average", 16, 0.1))
            hs = simulate(structure, ground, sub, method, -0.05, j_max=3, tol_displacement=0.02, tol_force=0.05)
            its, fc, switches = hs.iterations[1:], float(np.mean(hs.modes[1:, 0] == "force")), len(hs.switches)
            reference = ns
        wall = time.perf_counter() - t0
        sub.close()
        err, _ = max_error_pct(hs.u, reference.u)
        print(f"{method:>12} {its.mean():9.2f} {int(its.max()):4d} {fc * 100:8.0f}% {switches:9d} "
              f"{wall / hs.steps * 1e3:15.3f} {clock.now_s:13.1f} {err:18.3f}")


def whole_study() -> None:
    t0 = time.perf_counter()
    rows = study.fc_vs_dc()
    wall = time.perf_counter() - t0
    worst = max(abs(r.er_fc_pct - r.er_dc_pct) for r in rows)
    top = max(r.er_dc_pct for r in rows if r.dt == 0.02)
    top_fine = max(r.er_dc_pct for r in rows if r.dt == 0.005)
    print(f"\n3. fc-vs-dc study: {len(rows)} rows in {wall:.1f} s; max |Er FC - Er DC| = {worst:.2e} pp; "
          f"max Er {top:.2f} % at dt = 0.02, {top_fine:.2f} % at dt = 0.005")


def stiff_infill(duration_s: float = 4.0) -> None:
    from hsio import study_mixed
    from hsio.structures import get_structure

    structure = get_structure("structure_II_infill")
    print("\n4. structure_II_infill, delta_u 0.025 mm, load cell 0.01 kN, TR 10 ramp-hold")
    print(f"{'PGA g':>6} {'method':>14} {'error %':>9} {'switches':>9} {'not conv':>9} {'FC share':>9} {'wall (s)':>9}")
    for pga in (0.15, 0.2):
        ground = synthetic_record(duration_s=duration_s, dt=structure.dt, pga_g=pga, seed=1994)
        t0 = time.perf_counter()
        rows = study_mixed.run_case("structure_II_infill", structure, ground, study_mixed.METHODS, 0.025, 0.01)
        wall = (time.perf_counter() - t0) / len(rows)
        for r in rows:
            print(f"{pga:6.2f} {r.method:>14} {r.error_pct:9.3f} {r.switches:9d} {r.not_converged_steps:9d} "
                  f"{100 * r.fc_fraction:8.0f}% {wall:9.1f}")


if __name__ == "__main__":
    numerical_sdof()
    emulated_structure_I()
    whole_study()
    stiff_infill()
