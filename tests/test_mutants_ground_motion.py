"""Ground-motion records against exact values: scaling, cutting and resampling of a record whose
samples are known in closed form (a straight line is interpolated exactly, a sine within the
linear-interpolation bound h^2/8 max|a''|), unit sizes from their definitions (1 in = 25.4 mm,
standard gravity 9.80665 m/s^2), the bounds of each operation at their edges, and the synthetic
record's own properties (peak, length, reproducibility, no drift)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hsio.errors import RecordError
from hsio.ground_motion import (
    MAX_STEPS, SYNTHETIC_MIN_SAMPLES, GroundMotion, read_at2, read_columns, synthetic_record, unit_in_g,
)

DT = 0.01
LINE = GroundMotion("line", DT, 0.3 + 2.0 * np.arange(11) * DT)  # a(t) = 0.3 + 2 t over 0.1 s


def test_duration_and_peak_of_a_known_record():
    g = GroundMotion("r", 0.02, [0.1, -0.7, 0.4, 0.0])
    assert g.duration_s == pytest.approx(0.06, rel=1e-12)
    assert g.pga_g == 0.7


def test_scaled_multiplies_every_sample_and_keeps_the_step():
    g = GroundMotion("r", DT, [0.0, 0.5, -1.0]).scaled(2.5)
    assert np.array_equal(g.accel_g, [0.0, 1.25, -2.5]) and g.dt == DT and g.name == "r x 2.5"
    assert np.array_equal(GroundMotion("r", DT, [0.0, 0.5, -1.0]).scaled(-1).accel_g, [0.0, -0.5, 1.0])


@pytest.mark.parametrize("factor", [True, "2", None, float("nan"), float("inf")])
def test_scaled_refuses_what_is_not_a_finite_number(factor):
    with pytest.raises(RecordError, match="scale factor .* is not a finite number"):
        LINE.scaled(factor)


def test_acceleration_in_mm_s2_is_times_standard_gravity():
    assert np.array_equal(GroundMotion("r", DT, [1.0, -0.5]).acceleration_mm_s2(), [9806.65, -4903.325])


@pytest.mark.parametrize("duration, samples", [(0.05, 6), (DT, 2), (0.1, 11), (0.1 + 0.4 * DT, 11),
                                               (0.054, 6), (0.056, 7), (DT * (1 - 1e-9), 2), (0.1 + 0.5 * DT, 11)])
def test_truncated_keeps_the_first_samples_up_to_the_cut(duration, samples):
    g = LINE.truncated(duration)
    assert g.accel_g.size == samples and g.dt == DT
    assert np.array_equal(g.accel_g, LINE.accel_g[:samples])


@pytest.mark.parametrize("duration", [0.5 * DT, DT * (1 - 1e-6), 0.1 + 0.6 * DT, 0.0, -0.05])
def test_truncated_refuses_a_cut_shorter_than_a_step_or_longer_than_the_record(duration):
    with pytest.raises(RecordError, match="a cut to"):
        LINE.truncated(duration)


@pytest.mark.parametrize("dt, n", [(0.004, 26), (0.005, 21), (0.03, 4), (0.02, 6), (0.1, 2)])
def test_resampling_a_straight_line_is_exact(dt, n):
    g = LINE.resampled(dt)
    t = np.arange(n) * dt
    assert g.dt == dt and g.accel_g.size == n
    np.testing.assert_allclose(g.accel_g, 0.3 + 2.0 * t, rtol=0, atol=1e-12)


def test_resampling_a_sine_is_within_the_linear_interpolation_bound():
    w, h = 2 * math.pi * 3.0, 0.002
    g = GroundMotion("sine", h, np.sin(w * np.arange(501) * h)).resampled(0.0007)
    t = np.arange(g.accel_g.size) * 0.0007
    assert g.accel_g.size == int(1.0 / 0.0007 + 1e-9) + 1
    err = np.max(np.abs(g.accel_g - np.sin(w * t)))
    assert err <= h**2 / 8 * w**2 * (1 + 1e-9) and err > 0


def test_resampling_to_its_own_step_is_the_record_itself():
    assert LINE.resampled(DT) is LINE
    assert LINE.resampled(DT * (1 + 1e-13)) is LINE


def test_resampling_to_a_step_longer_than_the_record_is_refused():
    with pytest.raises(RecordError, match="shorter than one time step"):
        LINE.resampled(0.1 * (1 + 1e-6))
    assert LINE.resampled(0.1).accel_g.size == 2


def test_resampling_is_bounded_by_max_steps_exactly():
    one_s = GroundMotion("r", 0.5, [0.0, 1.0, 0.0])  # 1 s
    assert one_s.resampled(1.0 / MAX_STEPS).accel_g.size == MAX_STEPS + 1
    with pytest.raises(RecordError, match=f"more than the bound of {MAX_STEPS} steps"):
        one_s.resampled(1.0 / (MAX_STEPS + 1))


@pytest.mark.parametrize("unit, in_g", [
    ("in/s2", 0.0254 / 9.80665), ("IN/SEC/SEC", 0.0254 / 9.80665), ("in/s*s", 0.0254 / 9.80665),
    ("mm/s**2", 0.001 / 9.80665), ("gals", 0.01 / 9.80665), (" Cm / Sec ^ 2 ", 0.01 / 9.80665),
    ("(g)", 1.0), ("m/sec2.", 1 / 9.80665),
])
def test_unit_sizes_follow_from_their_definitions(unit, in_g):
    assert unit_in_g(unit) == pytest.approx(in_g, rel=1e-12)


def test_a_two_column_file_in_in_s2_is_read_exactly(tmp_path):
    path = tmp_path / "r.txt"
    path.write_text("0.00 386.0885826771654\n0.02 -193.0442913385827\n0.04 0\n0.06 38.60885826771654\n")
    g = read_columns(path, units="in/s^2")  # 386.0886 in/s^2 is 1 g
    assert g.dt == pytest.approx(0.02, rel=1e-12) and g.accel_g.size == 4
    np.testing.assert_allclose(g.accel_g, [1.0, -0.5, 0.0, 0.1], rtol=1e-12, atol=1e-15)


def test_a_one_column_file_takes_the_given_step(tmp_path):
    path = tmp_path / "r.txt"
    path.write_text("0.1\n-0.2\n0.3\n")
    g = read_columns(path, dt_s=0.005, units="g")
    assert g.dt == 0.005 and np.array_equal(g.accel_g, [0.1, -0.2, 0.3])


def test_two_columns_evenly_spaced_within_a_thousandth_of_a_step(tmp_path):
    path = tmp_path / "r.txt"
    path.write_text("0.0 1\n0.0100099 2\n0.02 3\n")  # a step off by 0.99e-3 of itself
    g = read_columns(path, units="g")
    assert g.dt == pytest.approx(0.01, rel=1e-12)
    path.write_text("0.0 1\n0.0100101 2\n0.02 3\n0.03 4\n")  # off by 1.01e-3
    with pytest.raises(RecordError, match=":2: the times are not evenly spaced"):
        read_columns(path, units="g")


@pytest.mark.parametrize("dt_s, ok", [(0.0100099, True), (0.0100101, False), (0.0099901, True), (0.0099899, False)])
def test_a_step_given_with_two_columns_agrees_within_a_thousandth(tmp_path, dt_s, ok):
    path = tmp_path / "r.txt"
    path.write_text("0.0 1\n0.01 2\n0.02 3\n")
    if ok:
        assert read_columns(path, dt_s=dt_s, units="g").dt == pytest.approx(0.01, rel=1e-12)
    else:
        with pytest.raises(RecordError, match="dt_s = .* but the times of the first column"):
            read_columns(path, dt_s=dt_s, units="g")


def test_the_first_time_that_does_not_increase_is_named(tmp_path):
    path = tmp_path / "r.txt"
    path.write_text("# c\n0.0 1\n0.01 2\n0.01 3\n0.03 4\n")
    with pytest.raises(RecordError, match=r":4: the times of the first column do not increase \(0.01 s, then 0.01 s\)"):
        read_columns(path, units="g")


def test_at2_values_several_to_a_line_in_their_order(tmp_path):
    path = tmp_path / "r.AT2"
    path.write_text("PEER\nrec\nACCELERATION IN UNITS OF G\nNPTS= 5, DT= 0.005 SEC\n 1.5E-01 -2.0E-01\n3 \n -4e-1 5\n")
    g = read_at2(path)
    assert g.dt == 0.005 and np.array_equal(g.accel_g, [0.15, -0.2, 3.0, -0.4, 5.0])


def test_synthetic_record_peak_length_and_step():
    g = synthetic_record(duration_s=4.0, dt=0.005, pga_g=0.45, seed=7)
    assert g.dt == 0.005 and g.accel_g.size == 801
    assert np.max(np.abs(g.accel_g)) == pytest.approx(0.45, rel=1e-12)


def test_synthetic_record_is_reproducible_per_seed_and_differs_between_seeds():
    a, b, c = (synthetic_record(duration_s=2.0, seed=s) for s in (3, 3, 4))
    assert np.array_equal(a.accel_g, b.accel_g) and not np.allclose(a.accel_g, c.accel_g)
    assert a.name == "synthetic (Kanai-Tajimi, seed 3)"


def test_synthetic_record_has_its_strong_motion_early_and_no_drift():
    """The envelope (t / t_peak)^2 exp(2 (1 - t / t_peak)) peaks at t_peak = 0.2 duration: the
    strong motion is in the first half, the last tenth is weak, and the 0.1 Hz high-pass leaves no
    offset."""
    g = synthetic_record(duration_s=20.0, dt=0.01, seed=1994)
    a, n = np.abs(g.accel_g), g.accel_g.size
    assert np.argmax(a) < n // 2
    assert np.max(a[int(0.9 * n):]) < 0.2 * g.pga_g
    assert abs(np.mean(g.accel_g)) < 0.01 * g.pga_g


def test_synthetic_record_follows_the_ground_filter_frequency():
    """Kanai-Tajimi filtered noise has its energy around f_g: the dominant frequency of the
    spectrum moves with f_g."""
    def dominant(f_g):
        g = synthetic_record(duration_s=20.0, dt=0.01, seed=5, f_g_hz=f_g, zeta_g=0.2)
        spectrum = np.abs(np.fft.rfft(g.accel_g)) ** 2
        f = np.fft.rfftfreq(g.accel_g.size, g.dt)
        return np.sum(f * spectrum) / np.sum(spectrum)
    low, high = dominant(1.0), dominant(8.0)
    assert 0.5 < low < 3.0 and 5.0 < high < 12.0


def test_synthetic_record_of_the_fewest_samples():
    dt = 0.01
    assert synthetic_record(duration_s=(SYNTHETIC_MIN_SAMPLES - 1) * dt, dt=dt).accel_g.size == SYNTHETIC_MIN_SAMPLES
    with pytest.raises(RecordError, match=r"is 9 samples; it needs at least 10 \(0.09 s\)"):
        synthetic_record(duration_s=(SYNTHETIC_MIN_SAMPLES - 2) * dt, dt=dt)


@pytest.mark.parametrize("dt", [0.0, -0.01])
def test_resampling_to_a_step_not_positive_is_refused(dt):
    with pytest.raises(RecordError, match="time step must be positive"):
        LINE.resampled(dt)


def test_the_first_sample_beyond_the_floating_point_range_is_named():
    g = GroundMotion("r", 0.5, [0.5, 3.0, 4.0])  # 3e308 and 4e308 overflow, 0.5e308 does not
    with pytest.raises(RecordError, match=r"r: sample 1 \(t = 0.500 s\) = 3 g is inf when scaled"):
        g.scaled(1e308)


def _at2(path, line4, values="0.1 0.2 0.3"):
    path.write_text(f"PEER\nrec\nACCELERATION TIME SERIES IN UNITS OF G\n{line4}\n{values}\n")
    return path


@pytest.mark.parametrize("dt_text", ["0", "-0.01", "-5"])
def test_an_at2_step_not_positive_is_named_so(tmp_path, dt_text):
    with pytest.raises(RecordError, match=rf"r.AT2:4: DT must be positive, got {float(dt_text)!r}"):
        read_at2(_at2(tmp_path / "r.AT2", f"NPTS= 3, DT= {dt_text} SEC"))


@pytest.mark.parametrize("dt_text", ["0.00001", "1.0"])
def test_an_at2_step_at_either_bound_is_read(tmp_path, dt_text):
    assert read_at2(_at2(tmp_path / "r.AT2", f"NPTS= 3, DT= {dt_text} SEC")).dt == float(dt_text)


@pytest.mark.parametrize("dt_text", ["0.0000099", "1.01"])
def test_an_at2_step_beyond_the_bounds_is_refused(tmp_path, dt_text):
    with pytest.raises(RecordError, match="out of bounds: a record's time step must be within 1e-05..1 s"):
        read_at2(_at2(tmp_path / "r.AT2", f"NPTS= 3, DT= {dt_text} SEC"))


def test_npts_at_its_bounds_is_taken_and_past_them_refused(tmp_path):
    assert read_at2(_at2(tmp_path / "r.AT2", "NPTS= 2, DT= 0.01 SEC", "0.1 0.2")).accel_g.size == 2
    with pytest.raises(RecordError, match="header says NPTS = 2000000, file holds 3 values"):
        read_at2(_at2(tmp_path / "r.AT2", "NPTS= 2000000, DT= 0.01 SEC"))  # within bounds: counted
    for npts in ("1", "2000001"):
        with pytest.raises(RecordError, match=f"NPTS = {npts} is out of bounds: within 2..2000000"):
            read_at2(_at2(tmp_path / "r.AT2", f"NPTS= {npts}, DT= 0.01 SEC"))


@pytest.mark.parametrize("digits, shown", [("1" * 18, "1" * 18), ("9" * 19, r"999999\.\.\. \(19 digits\)"),
                                           ("1234567" + "0" * 20, r"123456\.\.\. \(27 digits\)")])
def test_a_huge_npts_is_shown_whole_up_to_18_digits_then_in_part(tmp_path, digits, shown):
    with pytest.raises(RecordError, match=f":4: NPTS = {shown} is out of bounds"):
        read_at2(_at2(tmp_path / "r.AT2", f"NPTS= {digits}, DT= 0.01 SEC"))


@pytest.mark.parametrize("times, dt", [("0 1 2", 1.0), ("0 0.00001 0.00002", 1e-5)])
def test_two_columns_at_either_bound_of_the_step_are_read(tmp_path, times, dt):
    path = tmp_path / "r.txt"
    path.write_text("".join(f"{t} 0.{i}\n" for i, t in enumerate(times.split())))
    assert read_columns(path, units="g").dt == dt


@pytest.mark.parametrize("times", ["0 1.01 2.02", "0 0.0000099 0.0000198"])
def test_two_columns_beyond_the_bounds_of_the_step_are_refused(tmp_path, times):
    path = tmp_path / "r.txt"
    path.write_text("".join(f"{t} 0.{i}\n" for i, t in enumerate(times.split())))
    with pytest.raises(RecordError, match="r.txt: time step .* s is out of bounds: within 1e-05..1 s"):
        read_columns(path, units="g")


def test_the_ground_filter_frequency_is_below_nyquist_and_may_be_low():
    with pytest.raises(RecordError, match="f_g_hz = 50.0 Hz must be positive and below the Nyquist frequency"):
        synthetic_record(duration_s=1.0, dt=0.01, f_g_hz=50.0)
    for f_g in (0.5, 49.0):
        assert synthetic_record(duration_s=1.0, dt=0.01, f_g_hz=f_g).pga_g == pytest.approx(0.3, rel=1e-12)


def test_synthetic_records_follow_their_envelope_on_average():
    """Averaged over seeds, a^2 follows the square of the envelope (t / t_peak)^2 exp(2 (1 - t / t_peak)),
    t_peak = 0.2 duration: the profile of the mean square peaks near t_peak and has the envelope's shape."""
    duration, dt, seeds = 10.0, 0.01, 20
    mean_square = sum(synthetic_record(duration_s=duration, dt=dt, seed=s).accel_g ** 2 for s in range(seeds)) / seeds
    t = np.arange(mean_square.size) * dt
    x = t / (0.2 * duration)
    envelope2 = (x**2 * np.exp(2 * (1 - x))) ** 2
    smooth = np.convolve(mean_square, np.ones(50) / 50, mode="same")
    assert abs(t[np.argmax(smooth)] - 0.2 * duration) < 0.15 * duration
    assert np.corrcoef(smooth, envelope2)[0, 1] > 0.97


def test_synthetic_records_have_the_kanai_tajimi_spectrum_on_average():
    """Averaged over seeds, the power spectrum is that of the ground filter,
    |H|^2 = (w_g^4 + 4 zeta^2 w_g^2 w^2) / ((w_g^2 - w^2)^2 + 4 zeta^2 w_g^2 w^2): its peak at f_g and
    its shape within the scatter of 20 records over 0.5-25 Hz (the envelope widens each line by
    about 0.2 Hz, the bilinear transform warps it near Nyquist)."""
    duration, dt, f_g, zeta, seeds = 10.0, 0.01, 5.0, 0.3, 20
    power = 0.0
    for s in range(seeds):
        a = synthetic_record(duration_s=duration, dt=dt, seed=s, f_g_hz=f_g, zeta_g=zeta).accel_g
        power = power + np.abs(np.fft.rfft(a)) ** 2 / np.sum(a**2)
    f = np.fft.rfftfreq(a.size, dt)
    w, w_g = 2 * np.pi * f, 2 * np.pi * f_g
    H2 = (w_g**4 + 4 * zeta**2 * w_g**2 * w**2) / ((w_g**2 - w**2) ** 2 + 4 * zeta**2 * w_g**2 * w**2)
    smooth = np.convolve(power, np.ones(10) / 10, mode="same")
    band = (f > 0.5) & (f < 25.0)
    ratio = smooth[band] / H2[band]
    ratio /= np.median(ratio)
    assert abs(f[np.argmax(smooth)] - f_g) < 0.5
    low, high = np.percentile(ratio, [5, 95])
    assert 0.55 < low and high < 1.5, (low, high)  # measured 0.66, 1.28
