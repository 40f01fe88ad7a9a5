"""The hostile inputs that once gave a traceback, a hang or a MemoryError: each now gets a clear
error that names the file, line or key (exit 2 from `hsio run`). docs/faults.md lists the bounds."""

from __future__ import annotations

import socket
import subprocess
import sys
import threading

import pytest

from hsio import config
from hsio.drivers import modbus_map
from hsio.drivers.modbus import ModbusLink
from hsio.errors import CommunicationError, ConfigError, RecordError
from hsio.ground_motion import GroundMotion, read_at2

import numpy as np


def hsio(*args, cwd=None, timeout=120):
    return subprocess.run([sys.executable, "-m", "hsio.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, cwd=cwd)


def run_config(tmp_path, text: bytes | str, name="c.toml"):
    cfg = tmp_path / name
    if isinstance(text, str):
        cfg.write_text(text)
    else:
        cfg.write_bytes(text)
    return hsio("run", cfg, "--out", tmp_path / "o")


def assert_clear_error(proc, *words):
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-2000:])
    assert "Traceback" not in proc.stderr
    for w in words:
        assert w in proc.stderr, proc.stderr


def test_config_not_utf8_is_named(tmp_path):
    proc = run_config(tmp_path, b"[test]\nrate = 20.0\n# \xff\xfe caf\xe9\n", "latin.toml")
    assert_clear_error(proc, "latin.toml", "not UTF-8")


@pytest.mark.parametrize("text, words", [
    ("[test]\nrate = 1e9\n", ["[test] rate", "1000"]),
    ("[integrator]\nmethod = 'implicit_dc'\nj_max = 1000000000\ntol_displacement_mm = 0.0\n", ["[integrator] j_max", "100"]),
    ("[record]\nsynthetic_duration_s = 1e9\n", ["[record] synthetic_duration_s", "3600"]),
    ("[record]\nduration_s = 1e12\n", ["[record] duration_s"]),
    ("[test]\nn_avg = 100000000\n", ["[test] n_avg"]),
    ("[record]\nscale = 1e300\n", ["[record] scale"]),
])
def test_run_config_bounds_exit_2(tmp_path, text, words):
    assert_clear_error(run_config(tmp_path, text), *words)


def test_bounds_in_process_name_key_and_bound():
    with pytest.raises(ConfigError, match=r"\[test\] rate = 1000000000.0 is out of bounds.*0.001..1000"):
        config.from_dict({"test": {"rate": 1e9}})


def write_at2(path, header4, values):
    lines = ["PEER", "test record", "ACCELERATION TIME SERIES IN UNITS OF G", header4]
    lines += ["  ".join(values[i:i + 5]) for i in range(0, len(values), 5)]
    path.write_text("\n".join(lines) + "\n")


def test_at2_with_dt_1000_is_refused(tmp_path):
    f = tmp_path / "slow.AT2"
    write_at2(f, "NPTS=    5, DT= 1000.0 SEC", ["0.01"] * 5)
    with pytest.raises(RecordError, match=r"slow.AT2:4: DT = 1000 s is out of bounds"):
        read_at2(f)
    cfg = tmp_path / "c.toml"
    cfg.write_text('[record]\nfile = "slow.AT2"\n')
    assert_clear_error(hsio("run", cfg, "--out", tmp_path / "o"), "slow.AT2:4", "DT")


def test_at2_huge_npts_is_refused_before_reading(tmp_path):
    f = tmp_path / "big.AT2"
    write_at2(f, "NPTS= 999999999, DT= 0.01 SEC", ["0.01"] * 5)
    with pytest.raises(RecordError, match="NPTS = 999999999 is out of bounds"):
        read_at2(f)


def test_a_value_that_overflows_when_scaled_is_named_in_plain_numbers(tmp_path):
    """1.7e308 g is a finite value, read; scaled by -2 it is -inf: refused naming the file, the sample,
    the value and the factor (no numpy repr, no overflow warning)."""
    f = tmp_path / "huge.AT2"
    write_at2(f, "NPTS=    5, DT= 0.01 SEC", ["0.01", "1.7e308", "-0.01", "0.0", "0.01"])
    with pytest.raises(RecordError) as exc:
        read_at2(f).scaled(-2.0)
    assert str(exc.value) == ("huge.AT2: sample 1 (t = 0.010 s) = 1.7e+308 g is -inf when scaled by the factor -2: "
                              "beyond the largest floating-point number (1.798e+308)")
    cfg = tmp_path / "c.toml"
    cfg.write_text('[record]\nfile = "huge.AT2"\nscale = -2.0\n')
    proc = hsio("run", cfg, "--out", tmp_path / "o")
    assert_clear_error(proc, "huge.AT2: sample 1", "is -inf when scaled by the factor -2")
    assert "np.float64" not in proc.stderr and "RuntimeWarning" not in proc.stderr


def test_a_value_that_is_not_finite_is_named_in_plain_numbers():
    with pytest.raises(RecordError) as exc:
        GroundMotion("r", 0.01, np.array([0.0, 0.1, -np.inf]))
    assert str(exc.value) == "r: sample 2 (t = 0.020 s) is -inf, not a finite number"


def test_too_many_steps_are_refused():
    g = GroundMotion("long", 1.0, np.zeros(4001))
    with pytest.raises(RecordError, match="more than the bound of 1000000 steps"):
        g.resampled(0.001)


def test_url_with_port_99999(tmp_path):
    proc = run_config(tmp_path, '[hardware]\nurl = "modbus+tcp://127.0.0.1:99999"\n')
    assert_clear_error(proc, "99999", "port")


@pytest.mark.parametrize("url", ["modbus+tcp://[", "canopen+slcan://[::1/1", "modbus+tcp://127.0.0.1:0"])
def test_malformed_urls(tmp_path, url):
    assert_clear_error(run_config(tmp_path, f'[hardware]\nurl = "{url}"\n'), url)


def test_canopen_url_garbage(tmp_path):
    proc = run_config(tmp_path, '[hardware]\nurl = "canopen+virtual://x/abc"\n')
    assert_clear_error(proc, "node id")


DEFAULT = modbus_map.DEFAULT_MAP.read_text()


def write_map(tmp_path, old, new, name="m.toml"):
    assert old in DEFAULT
    path = tmp_path / name
    path.write_text(DEFAULT.replace(old, new))
    return path


@pytest.mark.parametrize("old, new, match", [
    ("max_axes = 8", "max_axes = 10000000", r"max_axes must be an integer in 1..64"),
    ("max_axes = 8", "max_axes = 1e7", r"max_axes must be an integer"),
    ("holding = 2 ", "holding = 3 ", r"\[status_bits\] holding and interlock share bit 3|interlock and holding share bit 3"),
    ("readwrite = true ", 'readwrite = "false" ', r"readwrite must be true or false"),
    ("base = 200\nstride = 8", "base = 200\nstride = 20000", r"\[status\] axis 7 ends at address|\[status\].*125"),
    ("device_id = 1", "device_id = 0", r"device_id must be an integer in 1..247 \(0 is broadcast\)"),
])
def test_unusable_register_maps_are_refused_at_load(tmp_path, old, new, match):
    with pytest.raises(ConfigError, match=match):
        modbus_map.load(write_map(tmp_path, old, new))


def test_status_span_checked_when_the_link_opens(tmp_path):
    path = write_map(tmp_path, "base = 200\nstride = 8", "base = 200\nstride = 60")
    regmap = modbus_map.load(path)  # one axis fits ...
    with pytest.raises(ConfigError, match="one Modbus read carries at most 125"):
        ModbusLink("modbus+tcp://127.0.0.1:5020", 3, {}, regmap)  # ... three do not: refused before connecting


def test_driver_map_resolves_beside_the_config_file(tmp_path, monkeypatch):
    sub = tmp_path / "lab"
    sub.mkdir()
    write_map(sub, "max_axes = 8", "max_axes = 4", name="ours.toml")
    cfg = sub / "run.toml"
    cfg.write_text('[hardware]\nurl = "modbus+tcp://127.0.0.1:5020"\n[driver]\nmap = "ours.toml"\n')
    monkeypatch.chdir(tmp_path)
    loaded = config.load(cfg)
    assert loaded["driver"]["map"] == str(sub / "ours.toml")
    assert modbus_map.load(loaded["driver"]["map"]).max_axes == 4


class EchoServer:
    """A TCP device that sends every request back as its reply (a miswired gateway)."""

    def __init__(self):
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(4)
        self.port = self.sock.getsockname()[1]
        self.stop = threading.Event()
        threading.Thread(target=self._run, daemon=True).start()

    def _run(self):
        self.sock.settimeout(0.1)
        while not self.stop.is_set():
            try:
                conn, _ = self.sock.accept()
            except OSError:
                continue
            threading.Thread(target=self._echo, args=(conn,), daemon=True).start()

    def _echo(self, conn):
        conn.settimeout(0.2)
        while not self.stop.is_set():
            try:
                data = conn.recv(4096)
            except TimeoutError:
                continue
            except OSError:
                break
            if not data:
                break
            conn.sendall(data)
        conn.close()

    def close(self):
        self.stop.set()
        self.sock.close()


def test_a_device_that_echoes_requests_is_a_communication_error():
    echo = EchoServer()
    try:
        link = ModbusLink(f"modbus+tcp://127.0.0.1:{echo.port}", 1, {"timeout_s": 0.2, "retries": 1,
                                                                        "reconnect_delay_s": 0.0})
        with pytest.raises(CommunicationError):
            link.open(enable=False)
            link.read_status()
        link.close()
    finally:
        echo.close()


def test_echo_device_from_the_cli(tmp_path):
    echo = EchoServer()
    try:
        proc = run_config(tmp_path, f'[hardware]\nurl = "modbus+tcp://127.0.0.1:{echo.port}"\n'
                                    '[driver]\ntimeout_s = 0.2\nretries = 1\nstroke_mm = 254.0\nforce_kN = 250.0\n')
    finally:
        echo.close()
    assert proc.returncode in (2, 3), proc.stderr
    assert "Traceback" not in proc.stderr and "127.0.0.1" in proc.stderr


# Failures the property-based tests found (tests/test_properties_parsers.py), kept as regular tests.

def test_found_map_modes_not_a_number(tmp_path):
    with pytest.raises(ConfigError, match=r"\[modes\] needs distinct whole numbers"):
        modbus_map.load(write_map(tmp_path, "force = 1\n", "force = {}\n"))


def test_found_map_address_true(tmp_path):
    with pytest.raises(ConfigError, match=r"register 'rate_hz': address must be an integer"):
        modbus_map.load(write_map(tmp_path, "rate_hz        = { address = 4,", "rate_hz        = { address = true,"))


def test_found_url_with_broken_ipv6_host():
    from hsio.drivers import canopen as canopen_driver
    from hsio.drivers.modbus import parse_options

    with pytest.raises(ConfigError, match="malformed"):
        parse_options("A://[", {})
    with pytest.raises(ConfigError, match="malformed"):
        canopen_driver.parse_url("canopen+virtual://[x/1", {})


@pytest.mark.parametrize("args, words", [
    (["probe", "modbus+tcp://["], ["malformed"]),
    (["probe", "modbus+tcp://127.0.0.1:99999"], ["99999"]),
    (["probe", "modbus+tcp://127.0.0.1:5", "--option", "timeout_s"], ["KEY=VALUE"]),
    (["emulate", "modbus", "--faults", "bogus@1"], ["unknown fault 'bogus'"]),
    (["emulate", "modbus", "--port", "99999"], ["99999"]),
    (["emulate", "modbus", "--watchdog-s", "0", "--watch-holding"], ["--watch-holding needs a watchdog"]),
    (["emulate", "canopen", "--slcan", "tcp", "--faults", "drop@x"], ["'x' is not a whole number"]),
])
def test_other_commands_refuse_bad_input_without_traceback(args, words):
    proc = hsio(*args)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    for w in words:
        assert w in proc.stderr + proc.stdout


def test_emulate_config_not_utf8(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_bytes(b"\xff\xfe[test]\n")
    proc = hsio("emulate", "modbus", bad)
    assert proc.returncode == 2 and "bad.toml" in proc.stderr and "not UTF-8" in proc.stderr


def test_diagnose_csv_not_utf8_is_named(tmp_path):
    path = tmp_path / "bad.csv"
    path.write_bytes(b"time_s,command_mm,measured_mm\n0,\xff\xfe1,2\n")
    assert_clear_error(hsio("diagnose", str(path)), "bad.csv", "UTF-8")


def test_diagnose_daq_header_line_without_a_colon(tmp_path):
    lines = ["Header Size:  7", "Version  2", "Sampling Interval:  0.001", "Sampling Rate:  1000",
             "Sample Count:  3", "Device Serial Number:  0",
             "Sample Number, Date/Time, CHANNEL0, CHANNEL1, CHANNEL2, Events"]
    lines += [f"{k},   06/29/2022 04:05:36.67{k} PM, 0.0{k}, 0.0{k}, 0.0{k}" for k in (1, 2, 3)]
    path = tmp_path / "daq.txt"
    path.write_text("\n".join(lines) + "\n")
    assert_clear_error(hsio("diagnose", str(path)), "daq.txt")


@pytest.fixture(scope="module")
def lockstep_record(tmp_path_factory):
    """A short lockstep run with its controller samples (what `hsio diagnose` reads)."""
    from hsio import runner

    out = tmp_path_factory.mktemp("record") / "run"
    runner.run(config.from_dict({"record": {"duration_s": 0.3}, "output": {"plots": False}}), out)
    return out


def _meta(key, value):
    import json

    return lambda db: db.execute("UPDATE meta SET value = ? WHERE key = ?", (json.dumps(value), key))


NAMES = "not those of its structure"  # the error budget checks the names against the structure
DAMAGED = [  # (id, damage, words of the samples' readers, words of the error budget: None, it reads no samples)
    ("no-actuator", _meta("actuator_names", []), "names no actuator", NAMES),
    ("actuator", _meta("actuator_names", ["zz"]), "the steps table has no target_zz", "the steps table has no target_zz"),
    ("dof", _meta("dof_names", ["zz"]), "the steps table has no u_zz", "the steps table has no u_zz"),
    ("config", _meta("config", 5), "meta config is 5, not a table", "meta config is 5, not a table"),
    ("text-sample", lambda db: db.execute("UPDATE samples SET disp_C1 = 'x' WHERE k = 3"), "samples cannot be read", None),
    ("no-samples", lambda db: db.execute("DROP TABLE samples"), "no such table: samples", None),
]


@pytest.mark.parametrize("damage, how, words", [
    pytest.param(damage, how, words if how != ["--run"] else budget, id=f"{name}-{how[0][2:] if how else 'actuator'}")
    for name, damage, words, budget in DAMAGED for how in ([], ["--specimen"], ["--run"])
    if how != ["--run"] or budget is not None])
def test_diagnose_of_a_damaged_run_record_is_named(tmp_path, lockstep_record, damage, how, words):
    """Each reader of a run record (the actuator's samples, the specimen's, the error budget's
    steps) names what is wrong with a damaged one, exit 2."""
    import shutil
    import sqlite3

    from click.testing import CliRunner

    from hsio.cli import main

    out = tmp_path / "run"
    shutil.copytree(lockstep_record, out)
    with sqlite3.connect(out / "run.sqlite") as db:
        damage(db)
    target = out if how == ["--run"] else out / "run.sqlite"
    result = CliRunner().invoke(main, ["diagnose", *how, str(target)])
    assert result.exit_code == 2 and not (result.exception and not isinstance(result.exception, SystemExit)), \
        (result.exit_code, result.exception, result.output[-600:])
    assert words in result.output
