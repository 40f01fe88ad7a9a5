"""Feed-forward compensation (docs/method.md section 4) on the emulated hockey-stick actuators.

For each structure, record and test rate, three continuous runs (hold_fraction = 0) on the same
emulated actuator: uncompensated; offline-compensated with a and b calibrated from the
uncompensated run (`hsio calibrate`); online-compensated starting from nothing. Prints the RMS
execution error d^c - d^m at the end of the steps (mm), the ratios against the uncompensated run,
and the HS-vs-NS maximum error.

    PYTHONPATH=. python bench/bench_compensation.py
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hsio import config as config_mod  # noqa: E402
from hsio import runner  # noqa: E402
from hsio.compensation import calibration  # noqa: E402
from hsio.ground_motion import GroundMotion  # noqa: E402
from hsio.recording import Run  # noqa: E402

CASES = [  # structure, label, [record] table or a ground motion built here
    ("structure_I", "synthetic 1.0 g, 5 s", {"pga_g": 1.0, "duration_s": 5.0}),
    ("structure_I", "sine 2 Hz 1.0 g, 4 s", "sine"),
    ("structure_II", "synthetic 0.3 g, 5 s", {"pga_g": 0.3, "duration_s": 5.0}),
]
RATES = (6.25, 40.0)


def sine(f_hz=2.0, pga_g=1.0, duration_s=4.0, dt=0.005) -> GroundMotion:
    t = np.arange(0.0, duration_s + 1e-9, dt)
    return GroundMotion(f"sine {f_hz} Hz", dt, pga_g * np.sin(2 * np.pi * f_hz * t) * np.minimum(t, 1.0))


def one_run(out: Path, structure: str, record, rate: float, compensation: dict):
    cfg = config_mod.from_dict({
        "structure": {"name": structure},
        "record": record if isinstance(record, dict) else {},
        "test": {"rate": rate, "hold_fraction": 0.0, "n_avg": 1},
        "emulator": {"preset": structure},
        "output": {"plots": False, "samples": False, "ns": True},
        "compensation": compensation,
    })
    summary = runner.run(cfg, out, ground=sine() if record == "sine" else None)
    run = Run(out / "run.sqlite")
    errors = np.column_stack([run.actuator("target", a) - run.actuator("disp", a) for a in run.actuator_names])
    return summary, errors


def rms(e: np.ndarray) -> float:
    return float(np.sqrt(np.mean(e**2)))


def main() -> None:
    header = (f"{'structure':<13}{'record':<22}{'TR':>6}  {'uncomp':>8}  {'a fit':>6} {'bd_max':>7}  {'offline':>8} {'x':>6}"
              f"  {'online':>8} {'x':>6} {'x 2nd':>6}   {'max err % off/offline/online':>28}  {'wall s':>6}")
    print("RMS execution error d^c - d^m at the end of the steps (mm), all actuators; x = reduction factor")
    print(header)
    print("-" * len(header))
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for structure, label, record in CASES:
            for rate in RATES:
                started = time.perf_counter()
                case = tmp / f"{structure}-{label.replace(' ', '_')}-TR{rate:g}"  # records are never overwritten
                off, e_off = one_run(case / "off", structure, record, rate, {"mode": "off"})
                cals = calibration.calibrate(case / "off")
                fit = cals[0].fit  # one actuator type per structure: the first actuator's calibration
                offline, e_offline = one_run(case / "offline", structure, record, rate,
                                             {"mode": "offline", "a_mm_s": fit.a_mm_s, "b_s_mm": fit.b_s_mm})
                online, e_online = one_run(case / "online", structure, record, rate, {"mode": "online"})
                half = len(e_off) // 2
                wall = time.perf_counter() - started
                print(f"{structure:<13}{label:<22}{rate:>6g}  {rms(e_off):8.4f}  {fit.a_mm_s:6.2f} {fit.lag_s * 1e3:5.1f}ms"
                      f"  {rms(e_offline):8.4f} {rms(e_off) / rms(e_offline):6.1f}  {rms(e_online):8.4f}"
                      f" {rms(e_off) / rms(e_online):6.1f} {rms(e_off[half:]) / rms(e_online[half:]):6.1f}   "
                      f"{off['max_error_pct']:9.2f} /{offline['max_error_pct']:7.2f} /{online['max_error_pct']:7.2f}  {wall:6.1f}")
    print("Sensor: resolution 0.025 mm, noise 0.01 mm (std); the noise floor of the RMS is about 0.012 mm.")
    print("Actuators: structure I a = 5.18 mm/s, b d_max = 20.0 ms; structure II a = 0.51 mm/s, b d_max = 30.0 ms.")


if __name__ == "__main__":
    main()
