"""A real OpenSees model whose trial goes beyond the stroke in the middle of its run: the session
stops (the actuators hold), and the model, answered NaN from then on, ends by itself
(docs/opensees.md, "A session that stops"). A genericClient whose connection is closed reads the
closed socket for ever instead."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from hsio.recording import Run
from test_opensees_support import QUIET, need_openseespy, serving, session_over, wait_for, write_config

STROKE_MM = 127.0  # the validation structure's actuators

# One DOF of mass 0.001 kN s^2/mm on C1 (K^EI 0.613 kN/mm, omega ~ 24.8 rad/s) under a constant
# force of 0.613 x 100 kN: x(t) = 100 (1 - cos omega t) mm passes the 127 mm stroke near t = 0.08 s.
# With two elements, a second DOF on C2 (0.536 kN/mm) under 0.536 x 10 kN stays within its stroke.
MODEL = """
import json, math, sys
import openseespy.opensees as ops
algorithm, ports = sys.argv[1], [int(x) for x in sys.argv[2:]]
ops.wipe()
ops.model("basic", "-ndm", 1, "-ndf", 1)
ops.node(1, 0.0)
ops.fix(1, 1)
ops.timeSeries("Constant", 1)
ops.pattern("Plain", 1, 1)
for k, (port, force) in enumerate(zip(ports, (0.613 * 100.0, 0.536 * 10.0))):
    ops.node(k + 2, 0.0)
    ops.mass(k + 2, 0.001)
    ops.element("genericClient", k + 1, "-node", k + 2, "-dof", 1, "-server", port, "127.0.0.1")
    ops.load(k + 2, force)
ops.constraints("Plain")
ops.numberer("Plain")
ops.system("FullGeneral")
if algorithm == "AlphaOS":
    ops.integrator("AlphaOS", 1.0)
    ops.algorithm("Linear")
    ops.test("FixedNumIter", 1)
else:
    ops.integrator("Newmark", 0.5, 0.25)
    ops.algorithm("Newton")
    ops.test("NormDispIncr", 1e-3, 10)
ops.analysis("Transient")
steps = []
for k in range(40):
    ok = ops.analyze(1, 0.01)
    steps.append([ok, ops.nodeDisp(2, 1)])
    if ok != 0 or not math.isfinite(steps[-1][1]):
        break
ops.wipe()
print("STEPS " + json.dumps(steps), flush=True)
"""


@pytest.mark.parametrize("algorithm, elements", [("AlphaOS", ["C1"]), ("Newton", ["C1"]), ("AlphaOS", ["C1", "C2"])])
def test_a_model_whose_trial_passes_the_stroke_ends_by_itself(tmp_path, algorithm, elements):
    """With two elements, C2 (within its stroke) is detached when C1 stops the session and is
    answered NaN too: the model ends, nothing of C2 moves after C1's fault either."""
    need_openseespy()
    script = tmp_path / "model.py"
    script.write_text(MODEL)
    config = write_config(tmp_path, "validation", elements, extra="timeout_s = 10.0\n" + QUIET)
    lines: list[str] = []
    at_fault: list[int] = []  # the lab's motions of the actuators when the session stopped

    def log(line: str) -> None:
        lines.append(line)
        if line.startswith("element C1: stopped:"):  # written by the lab's worker as the session stops
            at_fault.append(server.lab.trials)

    with serving(config, log=log) as server:
        proc = subprocess.run([sys.executable, str(script), algorithm, *map(str, server.ports)], capture_output=True,
                              text=True, timeout=30)  # on a closed connection it would spin until killed
        assert proc.returncode == 0, proc.stdout + proc.stderr
        assert wait_for(lambda: session_over(server))
        assert wait_for(lambda: sum("stopped session: DIE received" in line for line in lines) == len(elements))
        assert server.lab.sessions == 1  # the stopped client opened no session of its own
        trials = server.lab.trials
    steps = json.loads(proc.stdout.split("STEPS ", 1)[1])
    oks, u = np.array([s[0] for s in steps]), np.array([s[1] for s in steps])  # u: C1's DOF
    assert len(steps) < 40 and np.all(oks[:-1] == 0) and np.all(np.abs(u[:-1]) < STROKE_MM)
    if algorithm == "AlphaOS":  # one update per step: the step is done, its state not finite
        assert oks[-1] == 0 and np.isnan(u[-1])
    else:  # Newton: the norm of the increments is NaN, the step fails and analyze says so
        assert oks[-1] < 0 and "failed to converge" in proc.stderr
    record = Run(tmp_path / "records" / "run.sqlite")
    n = len(steps) - 1  # the steps before the one that went beyond the stroke
    assert record.summary["steps"] == n and record.steps["step"].tolist() == list(range(1, n + 1))
    assert "beyond the stroke" in record.summary["stopped"]
    assert record.summary["final_hold"] == "the actuators hold (confirmed by read-back)"
    events = {e["kind"]: e["message"] for e in record.events()}
    assert "beyond the stroke" in events["stop"] and "confirmed by read-back" in events["hold"]
    # nothing moved after the fault: the lab's count of motions did not change after it, and the
    # record has one compensation row per committed step, every sample's command within the stroke
    assert at_fault == [trials] and trials >= n, (at_fault, trials)
    assert record.compensation()["step"].tolist() == list(range(1, n + 1))
    samples = record.samples()
    for name in elements:
        assert samples[f"cmd_{name}"].size and np.all(np.abs(samples[f"cmd_{name}"]) < STROKE_MM)
    assert sum("the session stopped: nothing this client sends moves the actuators again" in line
               for line in lines) == len(elements)
    if len(elements) == 2:
        assert any(line.startswith("element C2: stopped: element C1 stopped the session") for line in lines), lines
