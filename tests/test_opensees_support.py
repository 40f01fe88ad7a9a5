"""Helpers of the OpenSees tests: servers in process or as `hsio serve opensees`, openseespy in a
subprocess, a raw genericClient (docs/opensees.md). Also the checks of the [opensees] table."""

from __future__ import annotations

import contextlib
import functools
import os
import re
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from hsio.errors import ConfigError
from hsio.opensees import protocol as p
from hsio.opensees.lab import Lab
from hsio.opensees.server import OpenSeesServer
from hsio.opensees.settings import parse, split_config
from hsio.runner import load_run_structure
from wire import terminate

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "opensees_structure.py"
QUIET = "[emulator]\nnoise_mm = 0.0\nresolution_mm = 0.0\nforce_noise_kN = 0.0\nforce_resolution_kN = 0.0\n"


@functools.lru_cache(maxsize=1)
def openseespy_problem() -> str:
    """Why openseespy cannot run here ('' when it can), checked once in a subprocess."""
    try:
        proc = subprocess.run([sys.executable, "-c", "import openseespy.opensees"], capture_output=True, text=True,
                              timeout=120)
    except subprocess.TimeoutExpired:
        return "importing openseespy took more than 120 s"
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or ["no message"])[-1]
        return (f"openseespy cannot be imported ({last}): pip install 'openseespy>=3.7,<4' and, on Debian, "
                f"apt-get install libblas3 liblapack3")
    return ""


def need_openseespy() -> None:
    problem = openseespy_problem()
    if problem:
        pytest.skip(problem)


def write_config(tmp_path: Path, structure: str, elements, extra: str = "", name: str = "serve.toml",
                 out: str = "records") -> Path:
    path = tmp_path / name
    names = ", ".join(f'"{e}"' for e in elements)
    path.write_text(f'[structure]\nname = "{structure}"\n[output]\nplots = false\n'
                    f'[opensees]\nelements = [{names}]\nout = "{tmp_path / out}"\n' + extra)
    return path


@contextlib.contextmanager
def serving(config: Path, log=None):
    """An in-process server of ``config`` on free ports; closed at the end."""
    settings, run = split_config(config)
    lines: list[str] = []
    lab = Lab(settings, run, load_run_structure(run), log=log or lines.append)
    server = OpenSeesServer(lab, "127.0.0.1", [0] * lab.n, log=log or lines.append).start()
    server.lines = lines
    try:
        yield server
    finally:
        server.close()


@contextlib.contextmanager
def cli_server(config: Path, out: Path, timeout_s: float = 60.0):
    """`hsio serve opensees --port 0 CONFIG` as a process; yields (process, {element: port})."""
    proc = subprocess.Popen([sys.executable, "-m", "hsio.cli", "serve", "opensees", "--port", "0", "--out", str(out),
                             str(config)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    ports: dict[str, int] = {}
    try:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            m = re.match(r"element (\S+) on 127\.0\.0\.1:(\d+)", line)
            if m:
                ports[m.group(1)] = int(m.group(2))
            if line.startswith("Ctrl-C"):
                break
        assert ports, f"the server printed no port: {proc.stderr.read() if proc.poll() is not None else ''}"
        yield proc, ports
    finally:
        terminate(proc, 30.0)
        proc.stdout.close()
        proc.stderr.close()


def run_model(structure: str, ports, out: Path, duration_s: float, timeout_s: float = 300.0, units: str = "kN-mm"):
    """The example OpenSees model in a subprocess (a crash cannot take pytest down): (u in mm, stdout)."""
    proc = subprocess.run([sys.executable, str(EXAMPLE), structure, "--ports", *map(str, ports), "--units", units,
                           "--duration", str(duration_s), "--out", str(out)], capture_output=True, text=True,
                          timeout=timeout_s, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return np.load(out), proc.stdout


class RawClient:
    """A genericClient speaking raw bytes: what a test or a hostile peer sends."""

    def __init__(self, port: int, timeout_s: float = 10.0):
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=timeout_s)
        self.data_size = 256

    def setup(self, n: int = 1, data_size: int = 256) -> None:
        s = p.element_setup(n, data_size)
        self.data_size = s.data_size
        self.sock.sendall(s.encode())

    def send(self, action: float, d=(), v=(), a=(), t: float = 0.0) -> None:
        frame = np.zeros(self.data_size)
        n = len(d)
        frame[0] = action
        frame[1:1 + n], frame[1 + n:1 + 2 * n], frame[1 + 2 * n:1 + 3 * n] = d, v or [0.0] * n, a or [0.0] * n
        frame[1 + 3 * n] = t
        self.sock.sendall(frame.astype("<f8").tobytes())

    def receive(self) -> np.ndarray:
        return np.frombuffer(bytes(p.recv_exact(self.sock, 8 * self.data_size)), dtype="<f8")

    def ask(self, action: int) -> np.ndarray:
        self.send(action)
        return self.receive()

    def step(self, d: float, t: float) -> float:
        self.send(p.SET_TRIAL, [d], t=t)
        force = float(self.ask(p.GET_FORCE)[0])
        self.send(p.COMMIT)
        return force

    def answered_as_stopped(self, n: int = 1, pending: bool = True, timeout_s: float = 5.0) -> bool:
        """True when the server treats this client as one whose session stopped on a fault
        (docs/opensees.md): the request in flight (``pending``: a getForce) is answered with NaN, a
        new trial moves nothing and its force, stiffness and displacement are NaN in the reply's
        slots (zeros after them), and DIE then closes the connection within ``timeout_s``."""
        self.sock.settimeout(timeout_s)
        replies = [(self.receive(), n)] if pending else []
        self.send(p.SET_TRIAL, [0.1] * n, t=1e3)
        replies += [(self.ask(p.GET_FORCE), n), (self.ask(p.GET_TANGENT_STIFF), n * n), (self.ask(p.GET_DISP), n)]
        self.send(p.COMMIT)
        self.send(p.DIE)
        answered = all(np.isnan(r[:k]).all() and not r[k:].any() for r, k in replies)
        return answered and self.closed_by_server(timeout_s)

    def closed_by_server(self, timeout_s: float = 5.0) -> bool:
        """True when the server has closed the connection (reads end) within ``timeout_s``."""
        self.sock.settimeout(timeout_s)
        try:
            for _ in range(1000):
                if not self.sock.recv(65536):
                    return True
        except (TimeoutError, socket.timeout):
            return False
        except OSError:
            return True
        return False

    def close(self) -> None:
        self.sock.close()


def wait_for(condition, timeout_s: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.02)
    return condition()


def session_over(server) -> bool:
    return server.lab._call(lambda: server.lab.site is None and not server.lab.active)


def step_together(clients, displacements, dt: float = 0.01) -> None:
    """The elements of one model make their steps k = 1, 2, ... together, as OpenSees does: every
    trial (displacement ``displacements[k - 1]``, time k dt) and its force, then every commit."""
    from hsio.opensees import protocol as p

    for k, d in enumerate(displacements, start=1):
        for c in clients:
            c.send(p.SET_TRIAL, [d], t=dt * k)
            c.ask(p.GET_FORCE)
        for c in clients:
            c.send(p.COMMIT)


def one_step_session(server, port_index: int = 0) -> None:
    """A client of the structure's element connects, makes one step of 1 mm (its force 0.3 to 0.9
    kN: the validation structure's cantilever, the preloaded column's lateral spring), says DIE and
    leaves; returns once the session is over."""
    from hsio.opensees import protocol as p

    c = RawClient(server.ports[port_index])
    c.setup()
    assert 0.3 < c.step(1.0, 0.01) < 0.9
    c.send(p.DIE)
    c.close()
    assert wait_for(lambda: session_over(server))


# --- the [opensees] table ---------------------------------------------------------------------

def test_opensees_table_is_checked_key_by_key():
    ok = parse({"elements": ["C1"], "length_factor": 1000.0, "force_factor": 0.001, "mass": {"C1": 0.1}}, "f.toml")
    assert ok.elements == ("C1",) and ok.length_factor == 1000.0 and ok.mass == {"C1": 0.1}
    for bad, words in [({}, "elements"), ({"elements": []}, "elements"), ({"elements": ["C1", "C1"]}, "distinct"),
                       ({"elements": ["C1"], "speed": 1}, "unknown key 'speed'"),
                       ({"elements": ["C1"], "length_factor": 0}, "length_factor must be positive"),
                       ({"elements": ["C1"], "stiffness": "tangent"}, "stiffness"),
                       ({"elements": ["C1"], "mass": {"C9": 1.0}}, "C9"),
                       ({"elements": ["C1"], "timeout_s": float("nan")}, "timeout_s"),
                       ({"elements": ["C1"], "timeout_s": 1e300}, "timeout_s must be between 0 and 86400"),
                       ({"elements": ["C1"], "force_factor": 1e-320}, "force_factor must be between 1e-06"),
                       ({"elements": ["C1"], "length_factor": 1e300}, "length_factor must be between"),
                       ({"elements": ["C1"], "mass": {"C1": [[1.0, 0.0], [0.0]]}}, "square matrix"),
                       ({"elements": ["C1"], "mass": {"C1": [[1.0, 0.2], [0.3, 1.0]]}}, r"symmetric: \[1\]\[0\]"),
                       ({"elements": ["C1"], "damping": {"C1": [[-1.0]]}}, r"damping.C1\[0\]\[0\] must not be negative"),
                       ({"elements": ["C1"], "mass": {"C1": [["a"]]}}, "finite number"),
                       ({"elements": ["C1"], "mass": {"C1": [[1.0, 5.0], [5.0, 1.0]]}}, "positive semidefinite.*-4")]:
        with pytest.raises(ConfigError, match=words):
            parse(bad, "f.toml")


def test_config_without_opensees_table_or_with_unknown_element_is_refused(tmp_path):
    plain = tmp_path / "plain.toml"
    plain.write_text('[structure]\nname = "validation"\n')
    with pytest.raises(ConfigError, match=r"no \[opensees\] table"):
        split_config(plain)
    bad = write_config(tmp_path, "validation", ["C3"])
    settings, run = split_config(bad)
    with pytest.raises(ConfigError, match=r"serve.toml: \[opensees\] elements: 'C3' is not an experimental element.*C1, C2"):
        Lab(settings, run, load_run_structure(run), log=lambda _: None)


def test_cli_bad_config_exits_2_without_traceback(tmp_path):
    bad = write_config(tmp_path, "validation", ["C3"])
    proc = subprocess.run([sys.executable, "-m", "hsio.cli", "serve", "opensees", "--port", "0", str(bad)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert "error:" in proc.stderr and "C3" in proc.stderr and "Traceback" not in proc.stderr


def test_setup_message_round_trip_and_column_major_matrices():
    s = p.element_setup(2)
    assert s == p.Setup.decode(s.encode()) and s.encode() == struct.pack("<11i", 2, 2, 2, 0, 1, 0, 0, 0, 2, 0, 256)
    s.check(2, "here")
    assert p.matrix_payload(np.array([[1.0, 2.0], [3.0, 4.0]])).tolist() == [1.0, 3.0, 2.0, 4.0]


def test_settings_a_server_does_not_read_are_named(tmp_path):
    """A server configuration copied from a run's: its record, integrator, dry run, plots and
    ledger are never read (OpenSees sends and integrates the motion), and the server names them."""
    from hsio.opensees.settings import split_config, unread_settings

    path = tmp_path / "serve.toml"
    path.write_text('[structure]\nname = "validation"\n[record]\npga_g = 0.3\n[integrator]\nmethod = "implicit_dc"\n'
                    '[test]\nrate = 10.0\nstart = "present"\n[output]\nplots = false\nsamples = true\n'
                    '[safety]\ndry_run = false\ninterlocks = true\n[opensees]\nelements = ["C1"]\n')
    _, run = split_config(path)
    assert unread_settings(run) == ["[record] pga_g", "[integrator] method", "[test] start", "[output] plots",
                                    "[safety] dry_run"]
    path.write_text('[structure]\nname = "validation"\n[test]\nrate = 10.0\n[opensees]\nelements = ["C1"]\n')
    assert unread_settings(split_config(path)[1]) == []
