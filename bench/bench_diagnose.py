"""Wall time of `hsio diagnose` on a 60 s record at 1 kHz: the real 0A.txt (61.5 s, where
../shared/data is present) and an emulator record of 60 s at 1000 Hz with effects hidden in it.

    PYTHONPATH=. python bench/bench_diagnose.py
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hsio.emulators.servo import ServoConfig  # noqa: E402
from hsio.diagnose.readers import read_record  # noqa: E402
from hsio.diagnose.report import write_report  # noqa: E402
from hsio.diagnose.selection import diagnose  # noqa: E402
from hsio.diagnose.synth import chirp_command, emulate  # noqa: E402

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "actuator" / "0A.txt"


def bench(name: str, read) -> None:
    t0 = time.perf_counter()
    record = read()
    t1 = time.perf_counter()
    d = diagnose(record)
    t2 = time.perf_counter()
    with tempfile.TemporaryDirectory() as out:
        write_report(d, out)
    t3 = time.perf_counter()
    print(f"{name}: {record.n} samples at {record.rate_hz:g} Hz ({record.duration_s:.1f} s)")
    print(f"  read {t1 - t0:6.2f} s   diagnose {t2 - t1:6.2f} s   report {t3 - t2:6.2f} s   total {t3 - t0:6.2f} s")
    print(f"  cause {d.cause}; extended {d.extended.name}; held-out RMS {d.baseline.rms_test_mm:.4f} -> "
          f"{d.extended.rms_test_mm:.4f} mm, gain {d.gain:.2f}")


def bench_specimen() -> None:
    """The specimen diagnosis of an emulated 60 s, 1 kHz specimen record with friction and a moving mass."""
    from hsio.diagnose.specimen_fit import diagnose_specimen
    from hsio.diagnose.synth import emulate_specimen
    from hsio.specimens import Diagnosed

    rate = 1000.0
    t0 = time.perf_counter()
    record = emulate_specimen(Diagnosed(k=1.0, c=0.01, friction_kN=0.5, friction_v0_mm_s=2.0, mass_kg=100.0),
                              chirp_command(60.0, rate, amplitude_mm=5.0, f0_hz=0.2, f1_hz=6.0), rate)
    t1 = time.perf_counter()
    d = diagnose_specimen(record)
    t2 = time.perf_counter()
    print(f"specimen, 60 s chirp at 1000 Hz, friction 0.5 kN + moving mass 100 kg: {record.n} samples")
    print(f"  emulate {t1 - t0:6.2f} s   diagnose {t2 - t1:6.2f} s")
    print(f"  cause {d.cause}; extended {d.extended.name}; scored RMS {d.baseline.rms_test_kN:.4f} -> "
          f"{d.extended.rms_test_kN:.4f} kN, gain {d.gain:.2f}")


def main() -> None:
    if DATA.exists():
        bench("0A.txt (MTS actuator, chirp)", lambda: read_record(DATA))
    else:
        print(f"{DATA} is absent: only the generated record")
    rate = 1000.0
    hidden = ServoConfig(rate_hz=rate, lag_s=0.02, transport_delay_s=0.005, backlash_mm=0.1, lag_retract_s=0.025)
    bench("emulator, 60 s chirp 0.2-8 Hz, delay 5 ms + backlash 0.1 mm + retract lag 25 ms",
          lambda: emulate(chirp_command(60.0, rate, amplitude_mm=3.0, f0_hz=0.2, f1_hz=8.0), hidden))
    bench_specimen()


if __name__ == "__main__":
    main()
