"""An OpenSees model (openseespy) of one of hsio's structures whose experimental elements are
genericClient elements served by `hsio serve opensees` (docs/opensees.md).

    hsio serve opensees examples/opensees_validation.toml          # C1 on 8090, C2 on 8091
    python examples/opensees_structure.py validation --ports 8090 8091

Each DOF of the structure is a node (1-D model in kN, mm, s, or N, m, s with --units N-m); each
experimental element is a one-node genericClient at its DOF (the actuator imposes the DOF's
displacement relative to the ground); the numerical springs and linear elements are zeroLength elements; the masses are nodal;
damping is mass-proportional (rayleigh alphaM); the ground motion is a UniformExcitation of the
record `hsio run` uses by default; the integrator is OpenSees' AlphaOS with alpha = 1 + hsio's
alpha, one update per step (a specimen cannot be reverted). Writes the displacement history in
mm (one row per step, one column per DOF) to --out (.npy).
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np


# Model units as (mm per model length unit, kN per model force unit).
UNITS = {"kN-mm": (1.0, 1.0), "N-m": (1000.0, 0.001)}


def build(ops, structure, ground_mm_s2: np.ndarray, ports, host: str = "127.0.0.1", alpha: float = -0.05,
          units: str = "kN-mm") -> None:
    """The model of ``structure`` in ``ops`` (openseespy.opensees), ready to analyze, in ``units``
    (the server's [opensees] length_factor and force_factor must say the same)."""
    mm, kN = UNITS[units]  # one model length unit is ``mm`` mm, one model force unit ``kN`` kN
    stiffness = mm / kN  # kN/mm -> model units
    mass = mm / kN  # kN s^2/mm -> model units (seconds on both sides)
    if structure.damping.kind != "mass":
        raise SystemExit(f"structure {structure.name}: this example models mass-proportional damping only")
    if len(ports) != len(structure.experimental):
        raise SystemExit(f"structure {structure.name} has {len(structure.experimental)} experimental elements "
                         f"({', '.join(e.name for e in structure.experimental)}): give as many --ports")
    ops.wipe()
    ops.model("basic", "-ndm", 1, "-ndf", 1)
    ground = 1000
    ops.node(ground, 0.0)
    ops.fix(ground, 1)
    for k, m in enumerate(structure.masses):
        ops.node(k + 1, 0.0)
        ops.mass(k + 1, float(m) * mass)
    tag = 1
    for element, port in zip(structure.experimental, ports):
        ops.element("genericClient", tag, "-node", element.dof + 1, "-dof", 1, "-server", int(port), host)
        tag += 1
    mat = 1
    for spring in structure.springs:
        ops.uniaxialMaterial("Elastic", mat, float(spring.k) * stiffness)
        j = ground if spring.j is None else spring.j + 1
        ops.element("zeroLength", tag, j, spring.i + 1, "-mat", mat, "-dir", 1)
        tag, mat = tag + 1, mat + 1
    for element in structure.numerical:
        if element.specimen.get("kind") != "linear":
            raise SystemExit(f"numerical element {element.name}: this example models linear elements only")
        ops.uniaxialMaterial("Elastic", mat, float(element.specimen["k"]) * stiffness)
        ops.element("zeroLength", tag, ground, element.dof + 1, "-mat", mat, "-dir", 1)
        tag, mat = tag + 1, mat + 1
    alpha_m = float(structure.C[0, 0] / structure.M[0, 0])
    ops.rayleigh(alpha_m, 0.0, 0.0, 0.0)
    ops.timeSeries("Path", 1, "-dt", float(structure.dt), "-values", *map(float, ground_mm_s2 / mm))
    ops.pattern("UniformExcitation", 1, 1, "-accel", 1)
    ops.constraints("Plain")
    ops.numberer("Plain")
    ops.system("FullGeneral")
    ops.test("FixedNumIter", 1)
    ops.algorithm("Linear")
    ops.integrator("AlphaOS", 1.0 + alpha)
    # At rest, with the record's first value acting: M a_0 = P_0 = -M iota a_g(0), as hsio starts.
    for k in range(structure.n_dof):
        ops.setNodeAccel(k + 1, 1, -float(ground_mm_s2[0]) / mm, "-commit")
    ops.analysis("Transient")


def run(structure_name: str, ports, host: str = "127.0.0.1", duration_s: float = 20.0, alpha: float = -0.05,
        units: str = "kN-mm"):
    """Displacements (steps + 1 x DOF, mm), wall time of the analysis (s)."""
    import openseespy.opensees as ops

    from hsio.ground_motion import synthetic_record
    from hsio.structures import get_structure

    structure = get_structure(structure_name)
    record = synthetic_record(duration_s=20.0, dt=structure.dt, pga_g=0.6, seed=1994)  # hsio run's default
    ag = record.truncated(duration_s).resampled(structure.dt).acceleration_mm_s2() if duration_s < 20.0 \
        else record.resampled(structure.dt).acceleration_mm_s2()
    build(ops, structure, ag, ports, host, alpha, units)
    n_steps = len(ag) - 1
    u = np.zeros((n_steps + 1, structure.n_dof))
    started = time.perf_counter()
    for k in range(1, n_steps + 1):
        if ops.analyze(1, float(structure.dt)) != 0:
            raise SystemExit(f"OpenSees: the analysis failed at step {k}")
        u[k] = [ops.nodeDisp(d + 1, 1) * UNITS[units][0] for d in range(structure.n_dof)]
    wall = time.perf_counter() - started
    ops.wipe()  # the genericClient elements send DIE: the servers end their sessions
    return u, wall


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("structure", choices=["validation", "structure_II"])
    parser.add_argument("--ports", type=int, nargs="+", required=True, help="one per experimental element, in order")
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--duration", type=float, default=20.0, help="seconds of the record (default: all of it)")
    parser.add_argument("--alpha", type=float, default=-0.05, help="hsio's alpha in [-1/3, 0]")
    parser.add_argument("--units", default="kN-mm", choices=sorted(UNITS),
                        help="units of the model (N-m: serve with length_factor = 1000, force_factor = 0.001)")
    parser.add_argument("--out", default=None, help="write the displacements (mm) here (.npy)")
    args = parser.parse_args(argv)
    u, wall = run(args.structure, args.ports, args.host, args.duration, args.alpha, args.units)
    steps = len(u) - 1
    print(f"{args.structure}: {steps} steps in {wall:.2f} s ({wall / max(steps, 1) * 1e3:.2f} ms per step)")
    print("peak displacement (mm): " + ", ".join(f"{x:.3f}" for x in np.max(np.abs(u), axis=0)))
    if args.out:
        np.save(args.out, u)
    return 0


if __name__ == "__main__":
    sys.exit(main())
