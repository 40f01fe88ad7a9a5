"""An OpenSees model (openseespy) of a cantilever column whose top is one genericClient element
with two basic DOFs, lateral displacement and rotation, served by `hsio serve opensees` on the
two actuators of the library structure column_two_actuators, through its setup
(docs/opensees.md, docs/setups.md).

    hsio serve opensees examples/opensees_column_two_actuators.toml   # the column on 8090
    python examples/opensees_setup.py --port 8090

The model is planar (ndm 2, ndf 3) in kN, mm, s: one node at the column top, at (0, L), with the
structure's masses on x and on the rotation, its vertical DOF fixed; the genericClient sits on
that node with `-dof 1 3` (x, then the rotation: the order of the element's `dofs`). Damping is
mass-proportional, ratio zeta on the first mode. The ground motion is `hsio run`'s default
record scaled to `--pga` (0.2 g). `--numerical` builds the same model with OpenSees' own
elasticBeamColumn (EI, L of the specimen, fixed base) in place of the genericClient: the
reference. `--integrator alphaos` (default) is AlphaOS with one update per step;
`--integrator newmark` is Newmark (average acceleration) with Newton iterations: the element
moves to every iterate, and only the committed ones are steps of the server's record. Writes the
top's history (one row per step: x in mm, rotation in rad) to --out (.npy); `--reference PATH`
also runs the numerical twin after the served model, writes its history there and prints the
largest difference, in % of each peak.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

STRUCTURE = "column_two_actuators"
E = 200.0  # kN/mm^2 of the numerical twin's column (only EI matters)


def build(ops, structure, ground_mm_s2: np.ndarray, port: int | None, host: str = "127.0.0.1",
          integrator: str = "alphaos", alpha: float = -0.05, zeta: float = 0.02) -> None:
    """The model in ``ops`` (openseespy.opensees), ready to analyze; ``port`` None: the numerical twin."""
    (element,) = structure.experimental
    L, EI = float(element.specimen["L"]), float(element.specimen["EI"])
    m_x, m_rot = (float(m) for m in structure.masses)
    ops.wipe()
    ops.model("basic", "-ndm", 2, "-ndf", 3)
    ops.node(1, 0.0, L)
    ops.fix(1, 0, 1, 0)
    ops.mass(1, m_x, 0.0, m_rot)
    if port is None:
        ops.node(2, 0.0, 0.0)
        ops.fix(2, 1, 1, 1)
        ops.geomTransf("Linear", 1)
        ops.element("elasticBeamColumn", 1, 2, 1, 1.0e4, E, EI / E, 1)
    else:
        ops.element("genericClient", 1, "-node", 1, "-dof", 1, 3, "-server", int(port), host)
    w1 = float(structure.modes()[0][0])
    ops.rayleigh(2.0 * zeta * w1, 0.0, 0.0, 0.0)
    ops.timeSeries("Path", 1, "-dt", float(structure.dt), "-values", *map(float, ground_mm_s2))
    ops.pattern("UniformExcitation", 1, 1, "-accel", 1)
    ops.constraints("Plain")
    ops.numberer("Plain")
    ops.system("FullGeneral")
    if integrator == "alphaos":
        ops.test("FixedNumIter", 1)
        ops.algorithm("Linear")
        ops.integrator("AlphaOS", 1.0 + alpha)
        # At rest, with the record's first value acting: M a_0 = -M iota a_g(0), as hsio starts.
        ops.setNodeAccel(1, 1, -float(ground_mm_s2[0]), "-commit")
    else:
        ops.test("NormDispIncr", 1.0e-4, 10)
        ops.algorithm("Newton")
        ops.integrator("Newmark", 0.5, 0.25)
    ops.analysis("Transient")


def run(port: int | None, host: str = "127.0.0.1", duration_s: float = 20.0, integrator: str = "alphaos",
        pga_g: float = 0.2):
    """The top's history (steps + 1 x 2: mm, rad) and the wall time of the analysis (s)."""
    import openseespy.opensees as ops

    from hsio.ground_motion import synthetic_record
    from hsio.structures import get_structure

    structure = get_structure(STRUCTURE)
    record = synthetic_record(duration_s=20.0, dt=structure.dt, pga_g=pga_g, seed=1994)  # hsio run's, scaled
    ag = (record.truncated(duration_s) if duration_s < 20.0 else record).resampled(structure.dt).acceleration_mm_s2()
    build(ops, structure, ag, port, host, integrator)
    n_steps = len(ag) - 1
    u = np.zeros((n_steps + 1, 2))
    started = time.perf_counter()
    for k in range(1, n_steps + 1):
        if ops.analyze(1, float(structure.dt)) != 0:
            raise SystemExit(f"OpenSees: the analysis failed at step {k}")
        u[k] = ops.nodeDisp(1, 1), ops.nodeDisp(1, 3)
    wall = time.perf_counter() - started
    ops.wipe()  # the genericClient sends DIE: the server ends its session
    return u, wall


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--port", type=int, help="the server's port of the column")
    where.add_argument("--numerical", action="store_true", help="OpenSees' own elasticBeamColumn instead")
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--duration", type=float, default=20.0, help="seconds of the record (default: all of it)")
    parser.add_argument("--integrator", default="alphaos", choices=["alphaos", "newmark"])
    parser.add_argument("--pga", type=float, default=0.2,
                        help="peak ground acceleration, g (hsio run's default record, scaled: at 0.2 g the upper "
                             "actuator needs about 95 mm of its 127 mm stroke over the 20 s; at 0.6 g, 280 mm)")
    parser.add_argument("--out", default=None, help="write the history (mm, rad) here (.npy)")
    parser.add_argument("--reference", default=None,
                        help="also run the numerical twin, write its history here (.npy) and compare")
    args = parser.parse_args(argv)
    u, wall = run(None if args.numerical else args.port, args.host, args.duration, args.integrator, args.pga)
    steps = len(u) - 1
    print(f"{STRUCTURE}: {steps} steps in {wall:.2f} s ({wall / max(steps, 1) * 1e3:.2f} ms per step)")
    peak = np.max(np.abs(u), axis=0)
    print(f"peak top displacement {peak[0]:.3f} mm, rotation {peak[1]:.3e} rad")
    if args.out:
        np.save(args.out, u)
    if args.reference:
        twin, _ = run(None, duration_s=args.duration, integrator=args.integrator, pga_g=args.pga)
        np.save(args.reference, twin)
        difference = np.max(np.abs(u - twin), axis=0) / np.max(np.abs(twin), axis=0) * 100.0
        print(f"against OpenSees' own elasticBeamColumn: x {difference[0]:.3f} %, rotation {difference[1]:.3f} % "
              f"of the peak")
    return 0


if __name__ == "__main__":
    sys.exit(main())
