"""Feed-forward compensation of actuator error (docs/method.md section 4): model, fit, eq. 2, online
estimation, and the whole loop on the emulated hockey-stick actuators of structures I and II."""

import json
import math
import re
import subprocess
import sys

import numpy as np
import pytest

from hsio.emulators.servo import PRESETS, ServoConfig, ServoController
from hsio import config as config_mod
from hsio import runner
from hsio.compensation import hockey_stick
from hsio.compensation.feedforward import FeedForward
from hsio.compensation.online import EstimatorSettings, OnlineEstimator
from hsio.compensation.stage import CompensationSettings, CompensationStage
from hsio.errors import ConfigError
from hsio.ground_motion import GroundMotion
from hsio.recording import Run
from hsio.specimens import make_specimen

A_I, B_I = 5.18, 7.874e-5
A_II, B_II = 0.51, 1.181e-4
RESOLUTION = 0.025


def harmonic(f_hz=2.0, pga_g=1.0, duration_s=4.0, dt=0.005) -> GroundMotion:
    """A sine of the ground, ramped in over 1 s: drives structure I to about +/-85 mm."""
    t = np.arange(0.0, duration_s + 1e-9, dt)
    return GroundMotion(f"sine {f_hz} Hz", dt, pga_g * np.sin(2 * np.pi * f_hz * t) * np.minimum(t, 1.0))


def run_structure_I(tmp_path, name, rate, compensation, ground=None, record=None):
    cfg = config_mod.from_dict({
        "structure": {"name": "structure_I"},
        "record": record or {"pga_g": 1.0, "duration_s": 5.0},
        "test": {"rate": rate, "hold_fraction": 0.0, "n_avg": 1},
        "emulator": {"preset": "structure_I"},
        "output": {"plots": False, "samples": False, "ns": False},
        "compensation": compensation,
    })
    out = tmp_path / name
    summary = runner.run(cfg, out, ground=ground)
    return summary, Run(out / "run.sqlite")


def execution_error(run: Run, actuator: str) -> np.ndarray:
    """d^c - d^m at the end of each step (the integrator's command minus the measurement)."""
    return run.actuator("target", actuator) - run.actuator("disp", actuator)


def rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


# -- the emulated actuator ------------------------------------------------------------------------

@pytest.mark.parametrize("preset", ["structure_I", "structure_II"])
def test_emulator_presets_follow_the_measured_hockey_stick(preset):
    a, b = PRESETS[preset]["a_mm_s"], PRESETS[preset]["b_s_mm"]
    cfg = ServoConfig.from_dict({"preset": preset, "noise_mm": 0.0, "resolution_mm": 0.0})
    for v in (1.0, 8.0, 20.0, 60.0):
        servo = ServoController(make_specimen({"kind": "linear", "k": 1.0}), cfg)
        for k in range(2048):  # a 2 s ramp: steady state
            servo.set_command(v * (k + 1) * servo.dt)
            servo.step()
        expected = 254.0 * b * max(v - a, 0.0)
        assert servo.command - servo.d_rod == pytest.approx(expected, abs=0.006), v


def test_emulator_preset_is_named_and_overridable():
    with pytest.raises(ConfigError, match="unknown preset 'structure_III'"):
        ServoConfig.from_dict({"preset": "structure_III"})
    assert ServoConfig.from_dict({"preset": "structure_I", "lag_s": 0.05}).lag_s == 0.05


# -- model, fit and eq. 2 ---------------------------------------------------------------------------

def test_fit_finds_threshold_and_slope_with_uncertainties():
    rng = np.random.default_rng(3)
    v = rng.uniform(-60, 60, 800)
    er = hockey_stick.error(v, 4.3, 9e-5) + rng.normal(0, 2e-5, v.size)
    fit = hockey_stick.fit(v, er)
    assert fit.a_mm_s == pytest.approx(4.3, rel=0.05)
    assert fit.b_s_mm == pytest.approx(9e-5, rel=0.01)
    assert abs(fit.a_mm_s - 4.3) < 4 * fit.a_std and abs(fit.b_s_mm - 9e-5) < 4 * fit.b_std
    assert fit.lag_s == pytest.approx(9e-5 * 254.0, rel=0.01)
    with pytest.raises(hockey_stick.FitError):
        hockey_stick.fit(np.zeros(50), rng.normal(0, 1e-5, 50))


@pytest.mark.parametrize("speeds", [[10.0], [10.0, -10.0], [2.0, 10.0]])
def test_one_speed_beyond_the_threshold_cannot_tell_a_from_b(speeds):
    """Steps at one speed beyond a (a ramp at constant velocity, or back and forth at it) give
    eq. 1's b (|v| - a) only as a product: any a below the speed fits with its b. The fit refuses
    rather than print one of them with an uncertainty of 0; below a (2 mm/s) nothing counts."""
    rng = np.random.default_rng(5)
    v = np.resize(np.array(speeds), 60)
    er = hockey_stick.error(v, 4.3, 9e-5) + rng.normal(0, 2e-6, v.size)
    with pytest.raises(hockey_stick.FitError, match=r"one speed \(10 mm/s\): eq. 1 fixes only b \(\|v\| - a\)"):
        hockey_stick.fit(v, er)


@pytest.mark.parametrize("form", ["lead", "eq2"])
def test_eq2_makes_the_model_land_on_the_command(form):
    t_d, a, lag = 0.2, A_I, B_I * 254.0
    ff = FeedForward(t_d, a, lag, form)
    d_c = 12.0 * t_d * np.arange(40)  # a 12 mm/s ramp
    d_a = np.array([ff.adjust(x) for x in d_c])
    v_a = np.diff(d_a) / t_d
    landed = d_a[1:] - lag * np.maximum(np.abs(v_a) - a, 0) * np.sign(v_a)
    assert np.allclose(landed[5:], d_c[1:][5:], atol=1e-9)
    below = FeedForward(t_d, a, lag, form)
    assert [below.adjust(x) for x in (0.0, 0.5, 1.0)] == [0.0, 0.5, 1.0]  # 2.5 mm/s: below a


def test_eq2_refuses_an_unstable_recursion():
    with pytest.raises(ValueError, match="unstable"):
        FeedForward(0.03125, A_I, B_I * 254.0, "eq2")  # TR 6.25: b d_max / t_d = 0.64
    with pytest.raises(ConfigError, match="unstable"):
        CompensationStage(["wall"], 0.03125, CompensationSettings(mode="offline", a_mm_s=A_I, b_s_mm=B_I, form="eq2"))


def test_online_estimator_is_bounded_and_rate_limited():
    settings = EstimatorSettings(window=200, update_every=10, min_samples=40, lag_max_s=0.05, lag_step_s=0.004)
    est = OnlineEstimator(settings)
    rng = np.random.default_rng(1)
    lags = []
    for _ in range(400):  # an absurd actuator: 1 s of lag
        v = rng.uniform(-50, 50)
        if est.observe(v, 1.0 * hockey_stick.excess_velocity(v, 2.0)):
            lags.append(est.lag)
    steps = np.diff([0.0, *lags])
    assert max(lags) <= 0.05 + 1e-12 and np.all(np.abs(steps) <= 0.004 + 1e-12)
    quiet = OnlineEstimator(settings)
    for _ in range(400):  # noise only: the lag stays zero
        quiet.observe(rng.uniform(-50, 50), rng.normal(0, 0.01))
    assert quiet.lag == 0.0 and quiet.a == 0.0 and quiet.updates == quiet.zero_updates
    still = OnlineEstimator(settings, a_mm_s=2.0, lag_s=0.01)
    for _ in range(400):  # no motion beyond the threshold: nothing is learnt, not even zero lag
        still.observe(rng.uniform(-2, 2), rng.normal(0, 0.01))
    assert still.updates == 0 and still.lag == 0.01 and still.rejected > 0


def lag_then_none(est: OnlineEstimator, lags, a_mm_s: float = 3.0, noise_mm: float = 0.005, seed: int = 2):
    """Feeds ``est`` one sample per step of an actuator whose lag is ``lags[i]`` (s) at step i
    (eq. 1, threshold ``a_mm_s``), under a sine of varying amplitude; the lag in use per step."""
    rng = np.random.default_rng(seed)
    used = []
    for i, lag in enumerate(lags):
        v = (20.0 + 20.0 * math.sin(2 * math.pi * i / 211)) * math.sin(2 * math.pi * i / 37)
        est.observe(v, lag * hockey_stick.excess_velocity(v, a_mm_s) + rng.normal(0.0, noise_mm))
        used.append(est.lag)
    return np.array(used)


def test_online_estimate_returns_to_zero_lag_when_the_lag_goes_away():
    """The actuator's lag is 20 ms, then 0: the estimate follows it there and back to exactly 0
    (a fit whose b is within two standard deviations of zero is zero lag), not staying at the
    last positive b the relative test accepted."""
    est = OnlineEstimator(EstimatorSettings())
    used = lag_then_none(est, [0.02] * 600 + [0.0] * 800)
    assert used[599] == pytest.approx(0.02, rel=0.1)
    assert used[-1] == 0.0 and est.zero_updates > 0
    assert np.all(np.abs(np.diff(used)) <= EstimatorSettings().lag_step_s + 1e-12)  # still rate-limited
    stays = OnlineEstimator(EstimatorSettings())  # a lag that stays is not taken for zero
    assert lag_then_none(stays, [0.02] * 1400)[600:] == pytest.approx(0.02, rel=0.1)
    assert stays.zero_updates == 0


# -- configuration -----------------------------------------------------------------------------------

@pytest.mark.parametrize("table, message", [
    ({"mode": "sometimes"}, "mode must be one of"),
    ({"mode": "offline"}, "needs the calibrated b_s_mm"),
    ({"mode": "online", "a_mm_s": -1.0}, "a_mm_s must be"),
    ({"mode": "online", "window": 10, "min_samples": 40}, "min_samples"),
    ({"mode": "online", "window": 100, "min_beyond": 101}, r"min_beyond \(101\) must not exceed window \(100\)"),
    ({"mode": "online", "actuators": "wall"}, "list of actuator names"),
    ({"mode": "online", "forgetting": 0.99}, "unknown key"),
    ({"mode": "online", "a_mm_s": 100.0}, r"starting a_mm_s = 100 is beyond a_max_mm_s = 50"),
    ({"mode": "online", "b_s_mm": 1.3e-4, "lag_max_s": 0.01}, r"starting lag .* = 0.03302 s is beyond lag_max_s = 0.01"),
])
def test_bad_compensation_table_is_named(table, message):
    with pytest.raises(ConfigError, match=message) as info:
        config_mod.from_dict({"compensation": table}, "lab.toml")
    assert "lab.toml" in str(info.value) and "[compensation]" in str(info.value)


def test_an_online_starting_guess_beyond_the_eq2_bound_is_refused_not_clamped():
    """With form = 'eq2' the online lag stays below 0.45 t_d (eq. 2's recursion is stable below
    t_d / 2); a starting guess beyond it is refused where the stage is built, before any step."""
    from hsio.compensation.stage import CompensationSettings, CompensationStage

    settings = CompensationSettings.from_table({"mode": "online", "form": "eq2", "b_s_mm": 1.3e-4})
    with pytest.raises(ConfigError, match=r"starting lag b d_max = 0.03302 s is beyond 0.45 t_d = 0.018 s"):
        CompensationStage(["wall"], 0.04, settings)
    assert CompensationStage(["wall"], 0.08, settings).feedforward[0].lag == pytest.approx(1.3e-4 * 254.0)


@pytest.mark.parametrize("settings, message", [
    ({"mode": "online", "a_mm_s": 100.0}, r"starting a_mm_s = 100 is beyond a_max_mm_s = 50"),
    ({"mode": "online", "b_s_mm": 1e-3}, r"starting lag .* = 0.254 s is beyond lag_max_s = 0.1"),
    ({"mode": "offline"}, "needs the calibrated b_s_mm"),
    ({"mode": "sometimes"}, "mode must be one of"),
    ({"mode": "online", "estimator": EstimatorSettings(window=0)}, "window must be"),
])
def test_settings_built_in_code_are_refused_like_the_table(settings, message):
    """CompensationSettings built in Python (docs/api.md) get the [compensation] table's checks
    where the stage is built: an online starting guess beyond its bounds is refused, not clamped."""
    with pytest.raises(ConfigError, match=message):
        CompensationStage(["wall"], 0.03125, CompensationSettings(**settings))


def test_offline_compensation_with_ramp_hold_is_refused():
    """a and b describe continuous ramps: with a ramp-hold the offline stage would overshoot."""
    table = {"mode": "offline", "a_mm_s": 5.0, "b_s_mm": 7.9e-5}
    with pytest.raises(ConfigError, match=r"hold_fraction = 0"):
        config_mod.from_dict({"compensation": table, "test": {"hold_fraction": 0.5}}, "lab.toml")
    config_mod.from_dict({"compensation": table, "test": {"hold_fraction": 0.0}}, "lab.toml")


def test_unknown_actuator_is_refused_before_anything_moves(tmp_path):
    cfg = config_mod.from_dict({"structure": {"name": "structure_I"}, "compensation": {"mode": "online", "actuators": ["BF"]}})
    with pytest.raises(ConfigError, match="unknown actuator.*BF.*known: wall"):
        runner.run(cfg, tmp_path / "x")


# -- calibration on an emulated run -------------------------------------------------------------------

def test_calibration_recovers_structure_I_within_5_percent(tmp_path):
    summary, run = run_structure_I(tmp_path, "cal", 6.25, {"mode": "off"})
    proc = subprocess.run([sys.executable, "-m", "hsio.cli", "calibrate", str(tmp_path / "cal"), "--json",
                           "--plot", str(tmp_path / "cal.png")], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    fit = json.loads(proc.stdout)
    assert set(fit) == {"a_mm_s", "b_s_mm", "lag_s", "a_std", "b_std", "n"}
    assert fit["a_mm_s"] == pytest.approx(A_I, rel=0.05)
    assert fit["b_s_mm"] == pytest.approx(B_I, rel=0.05)
    assert fit["lag_s"] == pytest.approx(fit["b_s_mm"] * 254.0)
    assert 0 < fit["a_std"] < 0.5 and 0 < fit["b_std"] < 5e-6 and fit["n"] > 900
    assert (tmp_path / "cal.png").stat().st_size > 10_000
    # The same steps as a CSV file (lab time per step) give the same fit.
    c, m = run.actuator("command", "wall"), run.actuator("disp", "wall")
    t = 0.03125 * np.arange(1, c.size + 1)
    csv = tmp_path / "steps.csv"
    csv.write_text("time_s,command_mm,measured_mm\n" + "".join(f"{a},{b},{d}\n" for a, b, d in zip(t, c, m)))
    proc = subprocess.run([sys.executable, "-m", "hsio.cli", "calibrate", str(csv), "--json"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["a_mm_s"] == pytest.approx(fit["a_mm_s"], rel=1e-6)
    csv.write_text("time_s,command_mm,measured_mm\n0,0,0\n0.1,0.2,x\n")
    proc = subprocess.run([sys.executable, "-m", "hsio.cli", "calibrate", str(csv)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "steps.csv:3: measured_mm 'x' is not a number" in proc.stderr


# -- compensation in the loop -------------------------------------------------------------------------

@pytest.mark.parametrize("rate", [6.25, 40.0])
def test_compensation_removes_the_execution_error(tmp_path, rate):
    ground = harmonic()
    off, run_off = run_structure_I(tmp_path, "off", rate, {"mode": "off"}, ground)
    offline, run_offline = run_structure_I(tmp_path, "offline", rate,
                                           {"mode": "offline", "a_mm_s": A_I, "b_s_mm": B_I}, ground)
    online, run_online = run_structure_I(tmp_path, "online", rate, {"mode": "online"}, ground)  # from nothing
    e_off, e_offline, e_online = (execution_error(r, "wall") for r in (run_off, run_offline, run_online))
    half = e_off.size // 2
    assert rms(e_off) / rms(e_offline) >= 10.0
    assert rms(e_offline) <= 2 * RESOLUTION
    assert rms(e_off) / rms(e_online) >= 5.0
    assert rms(e_off[half:]) / rms(e_online[half:]) >= 10.0
    assert rms(e_online[half:]) <= 2 * RESOLUTION
    # The summary reports what was used; the online estimate found the actuator by itself.
    assert offline["compensation"]["actuators"]["wall"]["a_mm_s"] == A_I
    learnt = online["compensation"]["actuators"]["wall"]
    assert learnt["updates"] > 0 and learnt["lag_s"] == pytest.approx(B_I * 254.0, rel=0.1)
    assert off["rms_tracking_error_mm"][0] == pytest.approx(rms(e_off))
    # Per step: Er^cc without compensation, Er^ca and Er^aa with it.
    table_off, table_on = run_off.compensation(), run_offline.compensation()
    assert np.allclose(table_off["er_cc_wall"] * 254.0, e_off) and np.all(np.isnan(table_off["er_ca_wall"]))
    assert np.allclose(table_on["er_ca_wall"] * 254.0, e_offline)
    sent = run_offline.actuator("command", "wall")
    assert np.allclose(table_on["er_aa_wall"] * 254.0, sent - run_offline.actuator("disp", "wall"))
    assert rms(table_on["er_aa_wall"]) > 5 * rms(table_on["er_ca_wall"])  # the actuator still lags what it is sent


def test_per_actuator_switch_structure_II(tmp_path):
    """BF compensated, IF not. 3 s of the record move the frames about 1.5 mm, so that IF's lag
    error stands well above the sensor floor (in the first 2 s they move 0.4 mm, and the
    uncompensated error is only twice the floor)."""
    cfg = config_mod.from_dict({
        "structure": {"name": "structure_II"}, "record": {"pga_g": 0.3, "duration_s": 3.0},
        "test": {"rate": 6.25, "hold_fraction": 0.0, "n_avg": 1}, "emulator": {"preset": "structure_II"},
        "output": {"plots": False, "samples": False, "ns": False},
        "compensation": {"mode": "offline", "a_mm_s": A_II, "b_s_mm": B_II, "actuators": ["BF"]},
    })
    summary = runner.run(cfg, tmp_path / "ii")
    run = Run(tmp_path / "ii" / "run.sqlite")
    table = run.compensation()
    used = summary["compensation"]["actuators"]
    assert used["BF"]["enabled"] and not used["IF"]["enabled"] and used["IF"]["lag_s"] == 0.0
    assert np.all(np.isnan(table["er_cc_BF"])) and np.all(np.isfinite(table["er_cc_IF"]))
    assert np.allclose(run.actuator("command", "IF"), run.actuator("target", "IF"))
    # the lag L = b d_max shows as the execution error's slope on the command velocity (eq. 1):
    # the uncompensated IF keeps it, the compensated BF has it removed; what is left on both is
    # the instruments' noise and resolution
    lag = B_II * 254.0
    t_d = 6.25 * 0.005
    slopes = {}
    for name in ("BF", "IF"):
        e, v = execution_error(run, name), np.gradient(run.actuator("target", name), t_d)
        slopes[name] = float(np.dot(e, v) / np.dot(v, v))
    assert slopes["IF"] > 0.4 * lag and abs(slopes["BF"]) < 0.1 * lag, slopes


def test_hs_vs_ns_error_of_structure_I_falls_with_compensation(tmp_path):
    base = ('[structure]\nname = "structure_I"\n[record]\npga_g = 1.0\nduration_s = 5.0\n'
            '[test]\nrate = 6.25\nhold_fraction = 0.0\nn_avg = 1\n[emulator]\npreset = "structure_I"\n'
            '[output]\nsamples = false\nplots = false\n')
    results = {}
    for mode, extra in (("off", ""), ("offline", f"a_mm_s = {A_I}\nb_s_mm = {B_I}\n"), ("online", "")):
        path = tmp_path / f"{mode}.toml"
        path.write_text(base + f'[compensation]\nmode = "{mode}"\n' + extra)
        proc = subprocess.run([sys.executable, "-m", "hsio.cli", "run", str(path), "--out", str(tmp_path / mode), "--json"],
                              capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, proc.stderr
        results[mode] = json.loads(proc.stdout)
    for s in results.values():
        assert {"max_error_pct", "rms_tracking_error_mm", "compensation"} <= set(s)
    assert results["offline"]["compensation"]["mode"] == "offline"
    assert results["off"]["max_error_pct"] > 5.0  # the lag of the hockey-stick actuator shows
    assert results["offline"]["max_error_pct"] < 0.2 * results["off"]["max_error_pct"]
    assert results["online"]["max_error_pct"] < 0.2 * results["off"]["max_error_pct"]
    assert results["offline"]["rms_tracking_error_mm"][0] < 0.1 * results["off"]["rms_tracking_error_mm"][0]


def test_online_starts_from_the_configured_guess():
    guess = CompensationSettings(mode="online", a_mm_s=4.0, b_s_mm=6e-5)
    stage = CompensationStage(["wall"], 0.2, guess)
    assert stage.feedforward[0].a == 4.0 and stage.feedforward[0].lag == pytest.approx(6e-5 * 254.0)
    nothing = CompensationStage(["wall"], 0.2, CompensationSettings(mode="online"))
    assert nothing.feedforward[0].lag == 0.0
    d_a = [nothing.adjust([x])[0] for x in (0.0, 2.0, 4.0)]
    assert d_a == [0.0, 2.0, 4.0]  # nothing learnt yet: commands pass unchanged


def test_a_test_rate_for_a_run_is_refused_rather_than_ignored(tmp_path):
    """--test-rate reads a CSV file's time_s as record time; a run records its own test rate, so
    the option given with a run is refused, naming --t-d as the way to set t_d."""
    from hsio.compensation import calibration
    from hsio.errors import RecordError

    (tmp_path / "run.sqlite").write_bytes(b"SQLite format 3\x00" + bytes(100))
    with pytest.raises(RecordError, match="a run records its own test rate .*--t-d"):
        calibration.load(tmp_path, test_rate=8.0)


def test_a_calibration_too_short_for_the_fit_names_the_steps_it_needs(tmp_path):
    """The fit takes five points after the first two steps, which give no velocity: a file of
    six steps is refused for its length, naming the seven a calibration needs."""
    from hsio.compensation import calibration
    from hsio.errors import RecordError

    csv = tmp_path / "six.csv"
    csv.write_text("time_s,command_mm,measured_mm\n" + "".join(f"{0.05 * i},{i * i},{i * i - 0.1 * i}\n" for i in range(6)))
    with pytest.raises(RecordError, match=r"six.csv: 6 data rows; a calibration needs at least 7 steps"):
        calibration.calibrate(csv)


def test_calibrating_an_implicit_run_warns_of_the_secant_average(tmp_path):
    """An implicit method records the secant estimator's average of the last secant_n_avg samples
    as each step's measurement (eq. 11), so the fitted lag is longer than the actuator's by
    (secant_n_avg - 1)/2 controller periods: the calibration says so, as it does for n_avg."""
    from hsio.compensation import calibration

    cfg = config_mod.from_dict({"structure": {"name": "structure_I"}, "record": {"pga_g": 1.0, "duration_s": 2.0},
                                "integrator": {"method": "implicit_dc", "secant_n_avg": 16},
                                "test": {"rate": 6.25, "hold_fraction": 0.0, "n_avg": 1},
                                "emulator": {"preset": "structure_I", "noise_mm": 0.0},
                                "output": {"plots": False, "samples": True, "ns": False}})
    runner.run(cfg, tmp_path / "dc")
    (cal,) = calibration.calibrate(tmp_path / "dc")
    assert any("average of the last 16 samples" in w and "7.5 controller periods" in w for w in cal.warnings), cal.warnings
    assert cal.fit.lag_s == pytest.approx(B_I * 254.0 + 7.5 / 1024, rel=0.05)


def test_calibration_through_setups_fits_the_actuators_strokes(tmp_path):
    """A column on two actuators through a setup records its basic DOFs (x and a rotation); the
    calibration is of each actuator's stroke, from the compensation table, by the actuator's
    name (as [compensation] actuators names them): b d_max is the emulator's lag on both."""
    from hsio.compensation import calibration

    cfg = config_mod.from_dict({"structure": {"name": "column_two_actuators"},
                                "record": {"pga_g": 0.3, "synthetic_duration_s": 0.6},
                                "test": {"rate": 10.0, "hold_fraction": 0.0, "n_avg": 1},
                                "emulator": {"lag_s": 0.03}, "output": {"plots": False}})
    runner.run(cfg, tmp_path / "col")
    cals = {c.actuator: c for c in calibration.calibrate(tmp_path / "col")}
    assert set(cals) == {"lower", "upper"}
    for cal in cals.values():
        assert cal.fit.b_s_mm * 254.0 == pytest.approx(0.03, rel=0.05)


def test_an_opensees_lab_compensates_through_setups_by_the_actuators_names(tmp_path):
    """`hsio serve opensees` builds the stage as `hsio run` does: through a setup, per actuator
    (lower, upper), so [compensation] actuators names an actuator (not a basic DOF)."""
    from test_opensees_support import QUIET, RawClient, serving, session_over, wait_for, write_config
    from hsio.opensees import protocol as p

    extra = ('[test]\nrate = 5\nhold_fraction = 0.0\nn_avg = 1\n[compensation]\nmode = "offline"\n'
             'a_mm_s = 0.0\nb_s_mm = 7.874e-5\nactuators = ["upper"]\n')
    config = write_config(tmp_path, "column_two_actuators", ["column"], extra=extra + QUIET)
    with serving(config) as server:
        c = RawClient(server.ports[0])
        try:
            c.setup(n=2)
            for k in range(3):
                c.send(p.SET_TRIAL, [0.001 * (k + 1), 0.0], t=0.01 * (k + 1))
                c.ask(p.GET_FORCE)
                c.send(p.COMMIT)
            used = server.lab._call(lambda: server.lab.site.compensation.summary())["actuators"]
            c.send(p.DIE)
        finally:
            c.close()
        assert wait_for(lambda: session_over(server)), server.lines
    assert not used["lower"]["enabled"] and used["upper"]["enabled"]
    assert used["upper"]["lag_s"] == pytest.approx(7.874e-5 * 254.0)


def test_a_record_of_an_opensees_lab_through_setups_calibrates_the_actuators(tmp_path):
    """`hsio serve opensees` records the compensation table as `hsio run` does: a record made
    through a setup (basic DOFs x and a rotation on two actuators) calibrates each actuator's
    stroke by its name, and b d_max is the emulator's lag on both."""
    from test_opensees_support import QUIET, RawClient, serving, session_over, wait_for, write_config
    from hsio.compensation import calibration
    from hsio.opensees import protocol as p

    extra = "[test]\nrate = 10\nhold_fraction = 0.0\nn_avg = 1\n"
    config = write_config(tmp_path, "column_two_actuators", ["column"], extra=extra + QUIET + "lag_s = 0.03\n")
    with serving(config) as server:
        c = RawClient(server.ports[0])
        try:
            c.setup(n=2)
            for k in range(1, 81):  # a sine of growing amplitude: motion at many speeds
                x = 0.25 * k * math.sin(2 * math.pi * k / 16)
                c.send(p.SET_TRIAL, [x, 2e-4 * x], t=0.01 * k)
                c.ask(p.GET_FORCE)
                c.send(p.COMMIT)
            c.send(p.DIE)
        finally:
            c.close()
        assert wait_for(lambda: session_over(server)), server.lines
    record = tmp_path / "records" / "run.sqlite"
    assert Run(record).summary["compensation"]["mode"] == "off"
    cals = {cal.actuator: cal for cal in calibration.calibrate(record)}
    assert set(cals) == {"lower", "upper"}
    for cal in cals.values():
        assert cal.fit.b_s_mm * 254.0 == pytest.approx(0.03, rel=0.05)


# -- per-actuator parameters --------------------------------------------------------------------------

def test_offline_parameters_per_actuator_default_to_the_shared_ones():
    """by_actuator gives an actuator its own a and b; the others (and a key it does not give)
    keep the shared values: each actuator's eq. 2 uses its own lag."""
    cfg = config_mod.from_dict({"structure": {"name": "column_two_actuators"},
                                "test": {"hold_fraction": 0.0},
                                "compensation": {"mode": "offline", "a_mm_s": 1.0, "b_s_mm": 5e-5,
                                                 "by_actuator": {"upper": {"b_s_mm": 1e-4}}}}, "lab.toml")
    stage = runner.compensation_stage(cfg, runner.load_run_structure(cfg))
    assert stage.names == ["lower", "upper"]
    assert [ff.a for ff in stage.feedforward] == [1.0, 1.0]
    assert [ff.lag for ff in stage.feedforward] == pytest.approx([5e-5 * 254.0, 1e-4 * 254.0])
    used = stage.summary()["actuators"]
    assert used["upper"]["b_s_mm"] == pytest.approx(1e-4) and used["lower"]["b_s_mm"] == pytest.approx(5e-5)
    # a command of 1 mm after one at rest (lead form, v = 1 mm / t_d): each moved ahead by its own lag
    stage.adjust([0.0, 0.0])
    d_a = stage.adjust([1.0, 1.0])
    v = 1.0 / stage.t_d
    assert d_a == pytest.approx([1.0 + 5e-5 * 254.0 * (v - 1.0), 1.0 + 1e-4 * 254.0 * (v - 1.0)])


@pytest.mark.parametrize("by_actuator, message", [
    ({"middle": {"b_s_mm": 1e-4}}, r"by_actuator.middle: unknown actuator 'middle'; known: lower, upper"),
    ({"upper": {"lag": 0.02}}, r"by_actuator.upper: unknown key 'lag'; known: a_mm_s, b_s_mm"),
    ({"upper": {"b_s_mm": -1e-4}}, r"by_actuator.upper.b_s_mm must be a number, zero or positive"),
    ({"upper": {"b_s_mm": 0.1}}, r"by_actuator.upper.b_s_mm x d_max_mm \(the lag\) = 25.4\d* is out of bounds: at most 10 s"),
    ({"upper": 1e-4}, r"by_actuator.upper must be a table"),
])
def test_a_bad_per_actuator_parameter_is_named(tmp_path, by_actuator, message):
    cfg = config_mod.from_dict({"structure": {"name": "column_two_actuators"}, "test": {"hold_fraction": 0.0},
                                "compensation": {"mode": "offline", "b_s_mm": 5e-5, "by_actuator": by_actuator}}, "lab.toml") \
        if "middle" in by_actuator else None
    if cfg is None:
        with pytest.raises(ConfigError, match=message) as info:
            config_mod.from_dict({"compensation": {"mode": "offline", "b_s_mm": 5e-5, "by_actuator": by_actuator}},
                                 "lab.toml")
    else:
        with pytest.raises(ConfigError, match=message) as info:
            runner.run(cfg, tmp_path / "x")  # refused before anything opens: no folder
        assert not (tmp_path / "x").exists()
    assert "lab.toml" in str(info.value) and "[compensation]" in str(info.value)


def test_offline_needs_a_b_for_every_compensated_actuator():
    """Without a shared b, an actuator that by_actuator gives no b is named; one left out of the
    compensation may not be given values (they would not be read)."""
    s = CompensationSettings(mode="offline", by_actuator={"upper": {"b_s_mm": 1e-4}})
    with pytest.raises(ConfigError, match=r"actuator 'lower': mode = 'offline' needs the calibrated b_s_mm"):
        CompensationStage(["lower", "upper"], 0.1, s)
    stage = CompensationStage(["lower", "upper"], 0.1, CompensationSettings(
        mode="offline", actuators=["upper"], by_actuator={"upper": {"b_s_mm": 1e-4}}))
    assert [ff.lag for ff in stage.feedforward] == pytest.approx([0.0, 1e-4 * 254.0])
    with pytest.raises(ConfigError, match=r"by_actuator.lower: actuator 'lower' is not compensated"):
        CompensationStage(["lower", "upper"], 0.1, CompensationSettings(
            mode="offline", b_s_mm=5e-5, actuators=["upper"], by_actuator={"lower": {"b_s_mm": 1e-4}}))


@pytest.mark.parametrize("z, zero", [(1.9, True), (2.1, False)])
def test_a_slope_within_two_standard_deviations_is_zero_lag(z, zero):
    """zero_fit: the slope b of e on x = sign(v)(|v| - a), through the origin, is zero lag when
    |b| <= 2 sigma_b; the residual is built orthogonal to x so that b and sigma_b are exact."""
    est = OnlineEstimator(EstimatorSettings())
    v = np.linspace(-60.0, 60.0, 121)
    v = v[v != 0]
    x = hockey_stick.excess_velocity(v, 0.0)
    r = np.cos(np.arange(v.size) * 0.7)
    r -= (r @ x) / (x @ x) * x  # orthogonal to x
    r *= 1e-4 / np.sqrt(r @ r / v.size)
    sigma_b = math.sqrt(float(r @ r) / (v.size - 1) / float(x @ x))
    fit = est.zero_fit(v, z * sigma_b * x + r)
    assert (fit is not None) is zero
    if zero:
        assert fit.b_std == pytest.approx(sigma_b, rel=1e-9)


def test_the_estimator_skips_samples_that_are_not_finite_and_refits_every_tenth_after_forty():
    est = OnlineEstimator(EstimatorSettings())
    assert est.rejected == est.updates == 0
    for v, e in ((float("nan"), 0.0), (5.0, float("inf")), (float("-inf"), float("nan"))):
        assert est.observe(v, e) is False
    assert len(est._v) == 0
    rng = np.random.default_rng(3)
    refits = []
    for i in range(1, 101):  # noise only: every refit is zero lag or rejected, counted either way
        before = est.updates + est.rejected
        est.observe(rng.uniform(-50, 50), rng.normal(0, 0.01))
        if est.updates + est.rejected > before:
            refits.append(i)
    assert refits == [40, 50, 60, 70, 80, 90, 100]
    for _ in range(500):
        est.observe(rng.uniform(-50, 50), rng.normal(0, 0.01))
    assert len(est._v) == 400  # the window


@pytest.mark.parametrize("start, message", [
    (dict(a_mm_s=60.0), "starting threshold a = 60.0 mm/s is out of bounds: 0 to a_max_mm_s = 50"),
    (dict(a_mm_s=-1.0), "starting threshold a = -1.0 mm/s is out of bounds"),
    (dict(a_mm_s=float("nan")), "starting threshold a = nan mm/s is out of bounds"),
    (dict(lag_s=0.2), "starting lag b d_max = 0.2 s is out of bounds: 0 to 0.1 s"),
    (dict(lag_s=0.02, lag_limit_s=0.01), "starting lag b d_max = 0.02 s is out of bounds: 0 to 0.01 s"),
    (dict(lag_s=-0.01), "starting lag b d_max = -0.01 s is out of bounds"),
])
def test_the_online_estimator_refuses_a_starting_guess_beyond_its_bounds(start, message):
    """As the [compensation] table does: the estimator built in code never clamps its start."""
    with pytest.raises(ValueError, match=re.escape(message)):
        OnlineEstimator(EstimatorSettings(), **start)
    edge = OnlineEstimator(EstimatorSettings(), a_mm_s=50.0, lag_s=0.1)
    assert (edge.a, edge.lag) == (50.0, 0.1)
