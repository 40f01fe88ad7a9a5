"""Benchmark: an OpenSees-driven run (openseespy genericClient elements served by hsio on
emulated actuators) beside `hsio run` of the same structure (docs/opensees.md).

Prints, per integration step: the wall time of `hsio run`; the wall time of the OpenSees-driven
run, split into the time inside the actuator site (command generation and the emulated
controllers, what `hsio run` also spends), the recording, and the rest (the genericClient protocol: framing,
sockets, the server's threads, and OpenSees' own solution); and the largest difference of the
two displacement histories (% of peak). Run: .venv/bin/python bench/bench_opensees.py [--duration S]

``--structure column_two_actuators``: the column top (x, rotation) as one two-DOF genericClient on
two emulated actuators through its setup (examples/opensees_setup.py), the record scaled to
0.2 g (the actuators' stroke), beside `hsio run` of the same structure with the OpenSees model's
mass-proportional damping.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from hsio import config as config_mod
from hsio import runner
from hsio.opensees.lab import Lab
from hsio.opensees.server import OpenSeesServer
from hsio.opensees.settings import split_config
from hsio.recording import Run
from hsio.result import max_error_pct

ROOT = Path(__file__).resolve().parents[1]
COLUMN = "column_two_actuators"
COLUMN_PGA_G = 0.2


def main() -> int:
    parser = argparse.ArgumentParser(description="OpenSees-driven run beside hsio run")
    parser.add_argument("--structure", default="validation", choices=["validation", "structure_II", COLUMN])
    parser.add_argument("--duration", type=float, default=5.0, help="seconds of the record (20: all of it)")
    args = parser.parse_args()
    probe = subprocess.run([sys.executable, "-c", "import openseespy.opensees"], capture_output=True, timeout=120)
    if probe.returncode != 0:
        print("bench_opensees: openseespy is not available (pip install 'openseespy>=3.7,<4'; "
              "apt-get install libblas3 liblapack3); skipped")
        return 0
    names = {"validation": ["C1", "C2"], "structure_II": ["BF", "IF"], COLUMN: ["column"]}[args.structure]
    dofs = {"validation": ["C1", "C2"], "structure_II": ["BF", "IF", "BF_mirror"],
            COLUMN: ["top_x", "top_rot"]}[args.structure]
    column = args.structure == COLUMN
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        run_toml = tmp / "run.toml"
        structure = f'name = "{args.structure}"'
        if column:  # the OpenSees model's damping: mass-proportional, 2 % on mode 1
            library = (ROOT / "hsio" / "library" / f"{COLUMN}.toml").read_text()
            (tmp / "column.toml").write_text(library.replace('kind = "rayleigh"', 'kind = "mass"'))
            structure = f'file = "{tmp / "column.toml"}"'
        run_toml.write_text(f'[structure]\n{structure}\n[record]\nduration_s = {args.duration}\n'
                            + (f"pga_g = {COLUMN_PGA_G}\n" if column else "") + "[output]\nplots = false\nns = false\n")
        hsio_wall = runner.run(config_mod.load(run_toml), tmp / "hsio")["wall_time_s"]  # the steps only
        reference = Run(tmp / "hsio" / "run.sqlite")
        steps = len(reference.steps["step"])

        serve_toml = tmp / "serve.toml"
        quoted = ", ".join(f'"{n}"' for n in names)
        serve_toml.write_text(f'[structure]\nname = "{args.structure}"\n[output]\nplots = false\n'
                              f'[opensees]\nelements = [{quoted}]\nout = "{tmp / "served"}"\n')
        settings, cfg = split_config(serve_toml)
        lab = Lab(settings, cfg, runner.load_run_structure(cfg), log=lambda _: None)
        with OpenSeesServer(lab, "127.0.0.1", [0] * lab.n, log=lambda _: None) as server:
            t0 = time.perf_counter()
            model = ([str(ROOT / "examples" / "opensees_setup.py"), "--port", str(server.ports[0]), "--pga",
                      str(COLUMN_PGA_G)] if column else
                     [str(ROOT / "examples" / "opensees_structure.py"), args.structure, "--ports", *map(str, server.ports)])
            proc = subprocess.run([sys.executable, *model, "--duration", str(args.duration), "--out", str(tmp / "u.npy")],
                                  capture_output=True, text=True, timeout=1800)
            os_wall = time.perf_counter() - t0
        if proc.returncode != 0:
            print(f"bench_opensees: the OpenSees model failed:\n{proc.stdout}{proc.stderr}")
            return 1
        served = Run(tmp / "served" / "run.sqlite")
        site_s = served.summary["site_time_s"]
        record_s = served.summary["record_time_s"]
        analysis_s = served.summary["wall_time_s"]
        u = np.load(tmp / "u.npy")
        worst, _ = max_error_pct(u[1:], np.column_stack([reference.dof("u", d) for d in dofs]))
    ms = 1e3 / steps
    print(f"{args.structure}, {steps} steps of the default record ({args.duration:g} s), emulated actuators, lockstep")
    print(f"hsio run                 {hsio_wall * ms:7.2f} ms per step")
    print(f"OpenSees via hsio serve  {analysis_s * ms:7.2f} ms per step (session; {os_wall * ms:.2f} with "
          f"openseespy's start-up)")
    print(f"  inside the site        {site_s * ms:7.2f} ms per step")
    print(f"  recording              {record_s * ms:7.2f} ms per step")
    rest = analysis_s - site_s - record_s
    print(f"  protocol and OpenSees  {rest * ms:7.2f} ms per step ({100 * rest / analysis_s:.0f} % of the step)")
    print(f"max |OpenSees - hsio run| {worst:.3f} % of peak displacement")
    return 0


if __name__ == "__main__":
    sys.exit(main())
