"""Bad input to the `hsio` command line: records, structure files, emulator and driver settings,
run folders, options and signals. Each case gets a clear error naming the file, table, key or
option and the bound (exit 2 from the command line): no traceback, no hang, no silent clamp, no
record in the wrong place."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hsio import config, runner
from hsio.clock import LockstepClock
from hsio.drivers import canopen as canopen_driver
from hsio.emulators.local import EmulatedActuator
from hsio.emulators.servo import ServoConfig, ServoController
from hsio.errors import ConfigError, RecordError
from hsio.ground_motion import read_at2
from hsio.recording import RecordExistsError
from hsio.specimens import make_specimen
from hsio.structure_file import load_structure, parse_structure
from hsio.structures import get_structure

from wire import write_config

SHORT = {"record": {"duration_s": 0.3}, "test": {"rate": 2.0}, "output": {"plots": False, "samples": False}}


def hsio(*args, cwd=None, timeout=60):
    return subprocess.run([sys.executable, "-m", "hsio.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, cwd=cwd)


def assert_exit_2(proc, *words):
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-2000:])
    assert "Traceback" not in proc.stderr, proc.stderr
    for w in words:
        assert w in proc.stderr, proc.stderr


def cfg(**tables):
    merged = {t: dict(kv) for t, kv in SHORT.items()}
    for t, kv in tables.items():
        merged.setdefault(t, {}).update(kv)
    return config.from_dict(merged, "run.toml")


# -- records ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("duration", [1e-9, 0.01, 0.05])
def test_a_synthetic_record_too_short_to_filter_is_named(duration):
    """Too few samples for the drift filter: named, not a scipy error."""
    with pytest.raises(ConfigError, match=r"\[record\] synthetic_duration_s = .*needs at least 10"):
        runner.build_record(cfg(record={"synthetic_duration_s": duration}), get_structure("validation"))


def test_a_cut_shorter_than_a_step_or_longer_than_the_record_is_refused():
    """duration_s = 1e-9 does not run one step, nor 100 s of a 20 s record 20 s: a cut, never a clamp."""
    structure = get_structure("validation")
    with pytest.raises(ConfigError, match=r"\[record\] duration_s = 1e-09.*shorter than one time step"):
        runner.build_record(cfg(record={"duration_s": 1e-9}), structure)
    with pytest.raises(ConfigError, match=r"\[record\] duration_s = 100.0 s is longer than the record .*20 s"):
        runner.build_record(cfg(record={"duration_s": 100.0}), structure)
    assert runner.build_record(cfg(record={"duration_s": 20.0}), structure).duration_s == pytest.approx(20.0)


def test_a_record_file_longer_than_the_duration_bound_is_refused(tmp_path):
    """A 2,000,000-sample file at 0.005 s (10,000 s, 1,000,000 steps) would run for hours: the
    3600 s bound of [record] duration_s holds for a file too, unless duration_s cuts it."""
    path = write_at2(tmp_path / "long.AT2", "ACCELERATION TIME SERIES IN UNITS OF G", ["0.01"] * 4000)
    path.write_text(path.read_text().replace("DT= 0.0100", "DT= 1.0000"))
    with pytest.raises(ConfigError, match=r"long.AT2: the record lasts 3999 s, beyond the bound of 3600 s"):
        runner.build_record(cfg(record={"file": str(path), "duration_s": 0.0}), get_structure("validation"))
    cut = runner.build_record(cfg(record={"file": str(path), "duration_s": 60.0}), get_structure("validation"))
    assert cut.duration_s == pytest.approx(60.0)


def write_at2(path, line3, values=("0.01", "0.02", "-0.01", "0.0", "0.01")):
    path.write_text("PEER NGA STRONG MOTION DATABASE RECORD\nrecord\n" + line3 + "\n"
                    f"NPTS= {len(values)}, DT= 0.0100 SEC\n" + "  ".join(values) + "\n")
    return path


@pytest.mark.parametrize("line3, words", [
    ("ACCELERATION TIME SERIES IN UNITS OF FT/S/S", "units of 'FT/S/S', which hsio does not know"),
    ("ACCELERATION TIME SERIES IN UNITS OF KN", "units of 'KN'"),
    ("VELOCITY TIME SERIES IN UNITS OF CM/S", "holds velocity"),
    ("DISPLACEMENT TIME SERIES IN UNITS OF CM", "holds displacement"),
])
def test_an_at2_record_in_a_unit_hsio_does_not_know_is_refused_naming_line_3(tmp_path, line3, words):
    """A record in an unknown unit read as g could run hundreds of times too strong."""
    path = write_at2(tmp_path / "r.AT2", line3)
    with pytest.raises(RecordError, match=r"r.AT2:3: ") as info:
        read_at2(path)
    assert words in str(info.value)


def test_at2_headers_in_g_are_read(tmp_path):
    for line3 in ("ACCELERATION TIME SERIES IN UNITS OF G", "ACCELERATION TIME HISTORY IN UNITS OF G.", "no units here"):
        assert read_at2(write_at2(tmp_path / "g.AT2", line3)).accel_g.size == 5


@pytest.mark.skipif(not os.path.exists("/dev/zero"), reason="needs /dev/zero")
def test_devices_are_refused_not_read_for_ever(tmp_path):
    """/dev/zero as a record, a structure file or a configuration would be read for ever."""
    with pytest.raises(RecordError, match="/dev/zero: not a regular file"):
        read_at2("/dev/zero")
    with pytest.raises(ConfigError, match="/dev/zero: not a regular file"):
        load_structure(Path("/dev/zero"))
    assert_exit_2(hsio("check", "/dev/zero", timeout=30), "not a regular file")
    with pytest.raises(ConfigError, match="/dev/zero: cannot read actuator model: not a regular file"):
        runner.check_hardware(cfg(hardware={"actuator_model": "/dev/zero"}))
    from hsio.drivers import modbus_map

    with pytest.raises(ConfigError, match="/dev/zero: cannot read register map: not a regular file"):
        modbus_map.load("/dev/zero")


# -- structure files --------------------------------------------------------------------------------

def structure_text(dt="0.01", m1="0.0017", extra="", iota=None):
    iota_line = f"iota = {iota}\n" if iota is not None else ""
    return (f'[structure]\nname = "s"\ndt = {dt}\n[[dof]]\nname = "A"\nmass = {m1}\n{iota_line}'
            '[[experimental]]\nname = "eA"\ndof = "A"\n' + (extra or 'model = { kind = "linear", k = 0.6 }\n'))


def test_structure_dt_beyond_its_bounds_is_named():
    """dt beyond 1e-5..1 s is named before any filter is designed."""
    with pytest.raises(ConfigError, match=r"s.toml: structure.dt: 100 s is out of bounds.*1e-05..1 s"):
        parse_structure(structure_text(dt="100"), "s.toml")
    with pytest.raises(ConfigError, match=r"structure.dt: 1e-07 s is out of bounds"):
        parse_structure(structure_text(dt="1e-7"), "s.toml")


@pytest.mark.parametrize("mass, words", [("1e-300", "Hz is out of bounds"), ("1e300", "Hz is out of bounds")])
def test_absurd_masses_are_named_not_taken_for_a_free_dof(mass, words):
    """A mass off by orders of magnitude is named as such, not as a DOF without a stiffness path."""
    with pytest.raises(ConfigError, match=words) as info:
        parse_structure(structure_text(m1=mass), "s.toml")
    assert "no stiffness path" not in str(info.value)


def test_a_floating_dof_is_still_named():
    text = structure_text() + '[[dof]]\nname = "B"\nmass = 0.001\n'
    with pytest.raises(ConfigError, match=r"dof\[1\]: DOF 'B' has no stiffness path"):
        parse_structure(text, "s.toml")


def test_every_iota_zero_is_refused():
    with pytest.raises(ConfigError, match="every DOF has iota = 0"):
        parse_structure(structure_text(iota="0.0"), "s.toml")


def test_a_structure_without_experimental_elements_is_refused_before_the_run(tmp_path):
    """Refused when the structure loads, before the control loop."""
    (tmp_path / "s.toml").write_text('[structure]\nname = "s"\ndt = 0.01\n[[dof]]\nname = "A"\nmass = 0.001\n'
                                     '[[spring]]\ndof = "A"\nk = 1.0\n')
    c = write_config(tmp_path, duration=0.3, extra='[structure]\nfile = "s.toml"\n')
    with pytest.raises(ConfigError, match=r"s.toml: the structure has no \[\[experimental\]\] element"):
        runner.load_run_structure(config.load(c))


@pytest.mark.parametrize("model, match", [
    ({"kind": "menegotto_pinto", "k0": 0.5, "u_y": 0.0, "theta": 0.1}, "menegotto_pinto: u_y must be positive"),
    ({"kind": "menegotto_pinto", "k0": 0.5, "u_y": 1.0, "theta": 0.1, "n": 0}, "menegotto_pinto: n must be positive"),
    ({"kind": "pinched_wood", "k0": 0.5, "F0": 0.0}, "pinched_wood: F0 must be positive"),
    ({"kind": "bilinear_gap", "k1": 0.5, "k2": 2.0, "gap": -1.0}, "bilinear_gap: gap must be zero or positive"),
])
def test_specimen_parameters_that_divide_by_zero_are_refused_at_load(model, match):
    """Refused when the file loads, not at the first step."""
    with pytest.raises(ConfigError, match=match):
        make_specimen(model)
    inline = "model = { " + ", ".join(f"{k} = {v!r}".replace("'", '"') for k, v in model.items()) + " }\n"
    with pytest.raises(ConfigError, match=r"experimental\[0\].model"):
        parse_structure(structure_text(extra=inline), "s.toml")


@pytest.mark.parametrize("n", [1.0, 2.0, 20.0, 1000.0, 1e6])
def test_a_near_bilinear_menegotto_pinto_spring_evaluates_without_overflow(n):
    """E&M 2007 eq. (13) with a large n (a spring close to bilinear, k0 then theta k0 beyond u_y):
    finite everywhere, odd, equal to the formula where its powers are representable, and the
    bilinear limit R = k0 u_y (theta x + (1 - theta) sign(x) min(|x|, 1)) for n = 1e6."""
    m = make_specimen({"kind": "menegotto_pinto", "k0": 60.0, "u_y": 5.0, "theta": 0.1, "n": n})
    for u in (1e-9, 0.5, 2.5, 5.0, 7.5, 10.0, 1e3, 1e9):
        x = u / 5.0
        R = m.trial(u)
        assert math.isfinite(R) and m.trial(-u) == pytest.approx(-R, rel=1e-15)
        if math.log10(max(x, 1e-300)) * n < 300:  # x^n representable: the formula as written
            assert R == pytest.approx(300.0 * (0.1 * x + 0.9 * x / (1.0 + x ** n) ** (1.0 / n)), rel=1e-12)
        if n == 1e6 and abs(x - 1.0) > 0.01:
            assert R == pytest.approx(300.0 * (0.1 * x + 0.9 * min(x, 1.0)), rel=1e-4)


def test_a_prediction_that_cannot_be_computed_is_bad_input_not_a_fault(tmp_path, monkeypatch):
    """NS failing along the record (a model that raises) exits 2 naming the step and the cause,
    says nothing was sent, and claims no recorded steps."""
    from hsio.specimens.elastic import MenegottoPinto

    def broken(self, u, dt=0.0):
        if abs(u) > 0.01:
            raise OverflowError(34, "Numerical result out of range")
        return self.k0 * u

    monkeypatch.setattr(MenegottoPinto, "trial", broken)
    c = tmp_path / "c.toml"
    c.write_text(f'[structure]\nfile = "{tmp_path / "s.toml"}"\n[record]\nsynthetic_duration_s = 0.5\n'
                 f'[output]\nplots = false\n')
    (tmp_path / "s.toml").write_text(structure_text(extra='model = { kind = "menegotto_pinto", k0 = 1.0, '
                                                          'u_y = 1.0, theta = 0.1, n = 2.0 }\n'))
    from click.testing import CliRunner
    from hsio.cli import main

    out = CliRunner().invoke(main, ["run", str(c), "--out", str(tmp_path / "run")])
    assert out.exit_code == 2, out.output
    assert "the prediction (NS" in out.output and "OverflowError" in out.output and "could not go past step" in out.output
    assert "Nothing was sent to the actuators" in out.output and "steps recorded" not in out.output


# -- the emulator -----------------------------------------------------------------------------------

@pytest.mark.parametrize("key, value, match", [
    ("seed", -1, r"seed = -1 is out of bounds"),
    ("transport_delay_s", 1e300, r"transport_delay_s = 1e\+300 is out of bounds: it must be within 0..3600 s"),
    ("lag_s", 1e9, r"lag_s = 1000000000.0 is out of bounds"),
    ("stroke_mm", 1e300, r"stroke_mm = 1e\+300 is out of bounds: it must be within 0..10000 mm"),
    ("rate_hz", 1e9, r"rate_hz = 1000000000.0 is out of bounds"),
    ("backlash_mm", 1e9, r"backlash_mm = 1000000000.0 is out of bounds: it must be within 0..254 mm"),
    ("displacement_gain", 0.0, r"displacement_gain must not be 0"),
    ("ki_per_s2", 1e12, r"ki_per_s2 = 1000000000000.0 is out of bounds: it must be within 0..1\.04858e\+06 1/s\^2"),
    ("compliance_mm_per_kN", 1e9, r"compliance_mm_per_kN = 1000000000.0 is out of bounds: it must be within 0..1000 mm/kN"),
])
def test_emulator_settings_beyond_sanity_bounds_are_named(key, value, match):
    """A 1e9 s lag, a 1e300 mm stroke, seed -1, a 1e300 s transport delay: each named with its bound."""
    with pytest.raises(ConfigError, match=r"run.toml: \[emulator\] " + match):
        cfg(emulator={key: value})


def test_the_emulator_refuses_a_rate_other_than_the_lockstep_clock():
    """[emulator] rate_hz = 1 in lockstep would run each 1/1024 s host tick as 1 s of emulated physics."""
    with pytest.raises(ConfigError, match=r"rate_hz = 500 differs from the experiment's controller rate \(1024 Hz\)"):
        EmulatedActuator("a", ServoController(make_specimen({"kind": "linear", "k": 1.0}), ServoConfig(rate_hz=500.0)),
                         LockstepClock())


def test_an_emulator_url_with_a_host_is_refused():
    with pytest.raises(ConfigError, match="emulator://somehost/.*takes no host or path"):
        cfg(hardware={"url": "emulator://somehost/"})


@pytest.mark.parametrize("table, match", [
    ({"mode": "online", "window": 10**12}, r"window = 1000000000000 is out of bounds: at most 1e\+06"),
    ({"mode": "offline", "a_mm_s": 1.0, "b_s_mm": 1e9}, r"b_s_mm x d_max_mm \(the lag\) = .* at most 10 s"),
    ({"mode": "online", "d_max_mm": 1e9}, r"d_max_mm = 1000000000.0 is out of bounds"),
])
def test_compensation_settings_beyond_sanity_bounds_are_named(table, match):
    """A 2.5e11 s lag to compensate, a window of 10^12 steps: each named with its bound."""
    with pytest.raises(ConfigError, match=r"\[compensation\]: " + match):
        cfg(compensation=table, test={"hold_fraction": 0.0})


# -- the run folder and the ledger ------------------------------------------------------------------

@pytest.mark.parametrize("make", ["under_a_file", "dangling_symlink", "empty"])
def test_a_run_folder_that_cannot_be_created_is_named(tmp_path, make):
    """Named with the reason, no traceback; --out "" is not the working directory."""
    (tmp_path / "f").write_text("x")
    os.symlink(tmp_path / "nowhere" / "x", tmp_path / "link")
    out = {"under_a_file": tmp_path / "f" / "sub", "dangling_symlink": tmp_path / "link", "empty": ""}[make]
    with pytest.raises(ConfigError, match="cannot create the run folder|empty path"):
        runner.run_folder(cfg(), get_structure("validation"), out)


@pytest.mark.parametrize("left", ["summary.json", "run.sqlite-wal", "run.sqlite-journal"])
def test_a_folder_with_what_is_left_of_a_record_is_refused(tmp_path, left):
    """A summary whose run.sqlite was moved away is not overwritten; a journal left without its
    database is not replayed into a new one."""
    (tmp_path / left).write_text("{}")
    with pytest.raises(RecordExistsError, match=f"holds {left} of an earlier run"):
        runner.run_folder(cfg(), get_structure("validation"), tmp_path)


@pytest.mark.parametrize("specimen_id", ["../../etc", "a/b", "..", "x\\y", "a\nb", " ", "tab\there", "nul\0"])
def test_a_specimen_id_is_a_plain_name(tmp_path, specimen_id, monkeypatch):
    """[specimen] id = "../../etc" does not put the ledger two folders above specimens/."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ConfigError, match=r"\[specimen\] id = .* is a plain name"):
        runner.open_ledger(cfg(specimen={"id": specimen_id}))
    assert not any(tmp_path.iterdir())


# -- hardware URLs and [driver] ---------------------------------------------------------------------

@pytest.mark.parametrize("url, driver, match", [
    ("modbus+tcp://127.0.0.1:99999", {}, "Port out of range"),
    ("modbus+tcp://127.0.0.1:5020", {"stroke_mm": "x"}, "stroke_mm must be a number"),
    ("canopen+virtual://x/1", {"eds": "nope.eds"}, "eds = 'nope.eds' is not a readable file"),
    ("canopen+slcan://127.0.0.1/1", {}, "an SLCAN adapter on TCP needs a port"),
])
def test_a_bad_url_or_driver_table_leaves_no_record(tmp_path, url, driver, match):
    """Checked before the run folder is created, so a typing error leaves no run.sqlite (and no used
    --out folder) behind: a [driver] stroke_mm that is not a number, a missing EDS, an SLCAN URL
    without a port."""
    c = cfg(hardware={"url": url}, driver=driver)
    with pytest.raises(ConfigError, match=match):
        runner.run(c, tmp_path / "o")
    assert not (tmp_path / "o").exists()
    with pytest.raises(ConfigError, match=match):  # hsio check: the dry run alone
        runner.predict(c, get_structure("validation"), runner.build_record(c, get_structure("validation")))


def test_a_driver_table_with_the_emulator_is_refused(tmp_path):
    """[driver] stroke_mm = 1 with emulator:// is not ignored: the run would go on with the
    emulator's 254 mm stroke, the operator believing it limited to 1 mm."""
    c = cfg(driver={"stroke_mm": 1.0})
    with pytest.raises(ConfigError, match=r"\[driver\] stroke_mm is not read with 'emulator://'"):
        runner.run(c, tmp_path / "o")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("url, hint", [("emulator", "did you mean 'emulator://'"), ("ftp://x", "known schemes"),
                                       ("http://127.0.0.1:80", "known schemes")])
def test_a_url_without_a_known_scheme_is_named_as_the_files_hardware_url(tmp_path, url, hint):
    """url = "emulator" (no ://) is named as [hardware] url of the file that gave it, not taken
    for an error in the [emulator] table."""
    path = tmp_path / "run.toml"
    path.write_text(f'[hardware]\nurl = "{url}"\n')
    with pytest.raises(ConfigError) as exc:
        config.load(path)
    message = str(exc.value)
    assert message.startswith(f"{path}: [hardware] url '{url}': unknown scheme") and hint in message
    assert "[emulator]" not in message


def test_canopen_url_check_is_the_drivers():
    with pytest.raises(ConfigError, match="node id 0 is not in 1..127"):
        canopen_driver.check_options("canopen+virtual://x/0", {})


# -- the command line -------------------------------------------------------------------------------

def write_calibration_csv(path):
    """A continuous record whose error is a hockey stick: a = 2 mm/s, b d_max = 20 ms."""
    rows, previous = ["time_s,command_mm,measured_mm"], 0.0
    for i in range(400):
        t = 0.1 * i
        command = 20 * math.sin(2 * math.pi * t / 8) * (1 + 0.5 * math.sin(t / 3))
        v = (command - previous) / 0.1
        previous = command
        error = math.copysign(0.02 * (abs(v) - 2), v) if abs(v) > 2 else 0.0
        rows.append(f"{t:.3f},{command:.5f},{command - error:.5f}")
    path.write_text("\n".join(rows) + "\n")


COMMAND_LINE = [
    (["run", "{c}", "--out", "{d}/a", "--out", "{d}/b"], "option --out is given twice"),
    (["emulate", "modbus", "--port", "0", "--port", "1"], "option --port is given twice"),
    (["calibrate", "{d}/x.csv", "--d-max", "inf"], "inf is not a finite number"),
    (["calibrate", "{d}/cal.csv", "--d-max", "1e-320"], "--d-max is the actuator's stroke in mm, 0.1 to 100000"),
    (["bench", "vrths", "--duration", "nan"], "nan is not a finite number"),
    (["run", "{c}", "--out", "{d}/f/sub"], "cannot create the run folder"),
    (["calibrate", "{d}/cal.csv", "--plot", "{d}/f/fig.png"], "cannot write the plot"),
    (["bench", "vrths", "--case", "1", "--data", "{d}/vrths"], "cannot be read"),
    (["emulate", "modbus-rtu", "--baudrate", "0"], "0 is not in the range"),
    (["serve", "opensees", "{d}/serve.toml", "--port", "0"], "unknown scheme 'http'"),
]


@pytest.mark.parametrize("args, words", COMMAND_LINE, ids=[w for _, w in COMMAND_LINE])
def test_command_line_refusals(tmp_path, args, words):
    """Options given twice (not the last one kept silently), nan and inf numbers, output paths that
    cannot be written, a benchmark folder that is not one: each named."""
    c = write_config(tmp_path, duration=0.3)
    (tmp_path / "f").write_text("x")
    (tmp_path / "vrths").mkdir()
    (tmp_path / "vrths" / "benchmark.json").write_text("{")
    (tmp_path / "vrths" / "elcentro_vrths.csv").write_text("x")
    write_calibration_csv(tmp_path / "cal.csv")
    (tmp_path / "serve.toml").write_text('[opensees]\nelements = ["C1"]\n[hardware]\nurl = "http://x"\n')
    assert_exit_2(hsio(*[a.format(c=c, d=tmp_path) for a in args]), words)
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_serve_refuses_a_records_folder_it_cannot_create(tmp_path):
    """Refused at start, not when the first OpenSees client connects; the emulated Modbus RTU server
    likewise with --baudrate 0."""
    (tmp_path / "f").write_text("x")
    (tmp_path / "serve.toml").write_text('[opensees]\nelements = ["C1"]\n')
    assert_exit_2(hsio("serve", "opensees", tmp_path / "serve.toml", "--port", "0", "--out", tmp_path / "f" / "x",
                       timeout=30), "cannot create the records folder")


def test_monitor_refuses_a_file_that_is_not_a_record(tmp_path):
    """A file that is not a record is named; the monitor does not serve a page for it."""
    (tmp_path / "run.sqlite").write_text("garbage" * 100)
    assert_exit_2(hsio("monitor", tmp_path, "--port", "0", timeout=30), "run.sqlite: not an hsio run record")


def test_a_second_ctrl_c_ends_with_a_message_not_a_blank_line(tmp_path):
    """A second SIGINT interrupts at once and ends with a message (not an empty 'hsio run: ' line)."""
    c = tmp_path / "run.toml"
    c.write_text("[record]\nsynthetic_duration_s = 60.0\n[output]\nplots = false\nsamples = false\n"
                 "[safety]\nkeys = false\n")
    proc = subprocess.Popen([sys.executable, "-m", "hsio.cli", "run", str(c), "--out", str(tmp_path / "o")],
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            line = proc.stderr.readline()
            if not line or "the actuators stand at" in line:
                break
        time.sleep(0.3)
        proc.send_signal(signal.SIGINT)
        time.sleep(0.02)
        proc.send_signal(signal.SIGINT)
        err = proc.stderr.read()
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stderr.close()
    assert proc.returncode == 5, (proc.returncode, err)
    assert "Traceback" not in err
    last = err.strip().splitlines()[-1]
    assert last.startswith("hsio run: ") and last.strip() != "hsio run:", err
    assert (tmp_path / "o" / "run.sqlite").exists()


# --- TOML files, driver limits and interlock thresholds -------------------------------------

def test_a_toml_file_that_is_a_device_or_too_large_is_refused_naming_it(tmp_path):
    from hsio.errors import ConfigError
    from hsio.opensees.settings import split_config

    with pytest.raises(ConfigError, match="/dev/zero: cannot read server configuration: not a regular file"):
        split_config("/dev/zero")
    big = tmp_path / "big.toml"
    big.write_text("# padding\n" * 500_000)
    with pytest.raises(ConfigError, match="big.toml: cannot read configuration: more than 4000000 bytes"):
        config.load(big)


def test_the_dry_run_checks_a_driver_limit_it_reads():
    from hsio.errors import ConfigError
    from hsio.safety.dry_run import known_limits

    with pytest.raises(ConfigError, match=r"\[driver\] .*stroke_mm must be a number, got 'x'"):
        known_limits("modbus+tcp://127.0.0.1:5020", {}, {"stroke_mm": "x"})
    with pytest.raises(ConfigError, match="velocity_mm_s must be positive"):
        known_limits("modbus+tcp://127.0.0.1:5020", {}, {"velocity_mm_s": -5.0})
    limits, source = known_limits("modbus+tcp://127.0.0.1:5020", {}, {"stroke_mm": 200})
    assert limits == {"stroke_mm": 200.0, "force_kN": None, "velocity_mm_s": 500.0} and source == "[driver]"


@pytest.mark.parametrize("key, value", [("following_time_s", 1e12), ("following_error_mm", 1e9), ("jump_kN", 1e9),
                                        ("force_drop_window_s", 1e7)])
def test_an_interlock_threshold_that_could_never_trip_is_refused(key, value):
    from hsio.errors import ConfigError

    with pytest.raises(ConfigError, match=rf"\[safety\]: {key} must be (positive and at most|within)"):
        config.from_dict({"safety": {key: value}}, "run.toml")


def test_a_modbus_url_without_a_port_names_the_default_port_it_tried():
    from hsio.clock import LockstepClock
    from hsio.errors import CommunicationError
    from hsio.hardware import open_hardware
    from hsio.structures import get_structure
    from wire import refused_port

    elements = list(get_structure("validation").experimental)
    with pytest.raises(CommunicationError, match=r"cannot connect to 127\.0\.0\.1:502 \(the Modbus TCP default port"):
        open_hardware("modbus+tcp://127.0.0.1", elements, LockstepClock(), {"timeout_s": 1.0})
    with refused_port() as port, pytest.raises(CommunicationError, match=rf"cannot connect to 127\.0\.0\.1:{port} \("):
        open_hardware(f"modbus+tcp://127.0.0.1:{port}", elements, LockstepClock(), {"timeout_s": 1.0})


def test_the_early_hardware_check_leaves_the_daq_keys_to_the_instruments():
    """[driver] instruments / instrument_map name the external instruments' DAQ module, not an
    option of the actuator driver: the check before the run folder passes them by, and still
    refuses an unknown key, a TCP URL without a host and a register map that does not load."""
    from hsio.errors import ConfigError
    from hsio.hardware import check_options

    url = "modbus+tcp://127.0.0.1:5020"
    check_options(url, {"instruments": "modbus+tcp://127.0.0.1:5021", "instrument_map": "daq.toml"})
    with pytest.raises(ConfigError, match="unknown key 'speed'"):
        check_options(url, {"speed": 1})
    with pytest.raises(ConfigError, match="expected modbus\\+tcp://HOST:PORT"):
        check_options("modbus+tcp://:5020", {})
    with pytest.raises(ConfigError, match="no-such-map.toml: cannot read register map"):
        check_options(url, {"map": "/nonexistent/no-such-map.toml"})


def test_a_saved_configuration_read_back_runs_the_record_it_ran():
    """A recorded run whose duration_s was longer than its record ran the whole record; read back
    (resume, error budget) it still does, while a new run with it is refused."""
    from hsio.errors import ConfigError
    from hsio.structures import get_structure

    cfg = config.from_dict({"record": {"synthetic_duration_s": 2.0, "duration_s": 5.0}}, "run.toml")
    structure = get_structure("validation")
    with pytest.raises(ConfigError, match="duration_s = 5.0 s is longer than the record.*synthetic_duration_s"):
        runner.build_record(cfg, structure)
    ground = runner.build_record(cfg, structure, replay=True)
    assert ground.duration_s == pytest.approx(2.0, abs=structure.dt)


def test_a_cut_longer_than_the_record_is_refused_from_python_too():
    from hsio.errors import RecordError
    from hsio.ground_motion import synthetic_record

    g = synthetic_record(duration_s=2.0, dt=0.01, pga_g=0.1, seed=1)
    with pytest.raises(RecordError, match="a cut to 5 s is longer than the record"):
        g.truncated(5.0)
    assert g.truncated(2.0).duration_s == pytest.approx(2.0)


def test_units_of_g_in_parentheses_are_read_as_g(tmp_path):
    from hsio.ground_motion import read_at2

    path = tmp_path / "g.AT2"
    path.write_text("PEER\nEVENT\nACCELERATION TIME SERIES IN UNITS OF (G)\nNPTS=  4, DT= .0100 SEC\n"
                    "0.0 0.1 -0.1 0.0\n")
    assert read_at2(path).accel_g.tolist() == [0.0, 0.1, -0.1, 0.0]


def test_out_naming_a_file_or_a_device_is_refused_plainly(tmp_path):
    """--out pointing at an existing file (or /dev/null) is named as not a folder, exit 2."""
    c = tmp_path / "c.toml"
    c.write_text('[record]\nsynthetic_duration_s = 0.2\n[output]\nplots = false\n')
    a_file = tmp_path / "a_file"
    a_file.write_text("keep me")
    for target in (a_file, Path("/dev/null")):
        if not target.exists():
            continue
        proc = hsio("run", c, "--out", target)
        assert_exit_2(proc, "--out", str(target), "is a file")
    assert a_file.read_text() == "keep me"


def test_an_unknown_compensated_actuator_names_the_configuration(tmp_path):
    c = tmp_path / "c.toml"
    c.write_text('[compensation]\nmode = "online"\nactuators = ["nope"]\n[record]\nsynthetic_duration_s = 0.2\n')
    proc = hsio("run", c, "--out", tmp_path / "run")
    assert_exit_2(proc, "c.toml: [compensation] actuators: unknown actuator(s) nope; known: C1, C2")
