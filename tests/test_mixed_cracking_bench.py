"""The attribution of bench/bench_mixed_cracking.py (docs/force_control.md, "Where DC's error after
cracking comes from"): before the infill cracks, DC's error is what the host reads of the
transducer; the bench's exact-sensor switch makes exactly that part exact and is undone after."""

from __future__ import annotations

import hsio.emulators.servo as servo


def test_exact_sensors_are_exact_and_restored(load_bench):
    bench = load_bench("bench_mixed_cracking")
    original = servo.ServoController._measure
    from hsio.specimens import make_specimen

    c = servo.ServoController(make_specimen({"kind": "linear", "k": 10.0}), servo.ServoConfig(noise_mm=0.01))
    with bench.sensors("both"):
        c.set_command(0.3)
        c.advance(50)
        assert c.measured_displacement == c.d_spec and c._rod_feedback == c.d_rod
    with bench.sensors("reading"):
        c.advance(5)
        assert c.measured_displacement == c.d_spec and c._rod_feedback != c.d_rod  # the loop still reads noise
    assert servo.ServoController._measure is original
    c.advance(5)
    assert c.measured_displacement != c.d_spec


def test_before_cracking_dc_error_is_the_hosts_reading(load_bench):
    bench = load_bench("bench_mixed_cracking")
    before, after = bench.run(0.2, 1994, "implicit_dc", 10)
    exact_before, _ = bench.run(0.2, 1994, "implicit_dc", 10, "reading")
    assert after is not None  # this record cracks the infill
    assert before > 0.3 and exact_before < 0.1 * before
