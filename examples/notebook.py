"""hsio from Python, as in a notebook: a structure, a record, NS and HS, a DataFrame and a plot.

Run it with ``.venv/bin/python examples/notebook.py [OUT_DIR]``; it writes ``hs_vs_ns.png`` and
``steps.csv`` in OUT_DIR (default: runs/notebook).
"""

import sys
from pathlib import Path

import hsio

out = Path(sys.argv[1] if len(sys.argv) > 1 else "runs/notebook")
try:
    out.mkdir(parents=True, exist_ok=True)
except OSError as exc:  # a file of that name, a folder that cannot be written
    print(f"notebook.py: cannot use {str(out)!r} as the output folder: {exc.strerror}", file=sys.stderr)
    sys.exit(2)

# 1. The structure: a shipped one by name, or your own file (docs/structures.md).
structure = hsio.load_structure("validation")
print(structure.name, [f"{f:.2f} Hz" for f in structure.natural_frequencies_hz()])

# 2. The record: a PEER .AT2 file (hsio.read_at2(path).scaled(0.17)) or a synthetic one.
ground = hsio.synthetic_record(duration_s=5.0, dt=structure.dt, pga_g=0.5, seed=7)

# 3. The purely numerical simulation (the specimen models in place of the actuators).
ns = hsio.run_numerical(structure, ground, method="alpha_os", alpha=-0.05)

# 4. The hybrid simulation on emulated actuators: the same loop a lab runs on real ones
#    ("modbus+tcp://HOST:PORT", "canopen+socketcan://can0/1", ...).
with hsio.open_site(structure, "emulator://", test_rate=20.0, hold_fraction=0.5, n_avg=4,
                    options={"lag_s": 0.02}) as site:
    hs = hsio.simulate(structure, ground, site, method="alpha_os", alpha=-0.05)

worst, per_dof = hsio.max_error_pct(hs.u, ns.u)
print(f"{hs.steps} steps; max |HS - NS| = {worst:.3f} % of the peak")

# 5. The histories as a DataFrame (pandas: pip install 'hsio[dataframe]') and a plot.
frame = hs.to_dataframe()
frame.to_csv(out / "steps.csv")
print(frame[["time_s", "u_C1", "u_C2", "force_C1", "force_C2"]].describe().loc[["min", "max"]])
hs.plot(out / "hs_vs_ns.png", reference=ns)
print(f"wrote {out / 'steps.csv'} and {out / 'hs_vs_ns.png'}")
