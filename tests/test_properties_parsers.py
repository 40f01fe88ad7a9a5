"""Property-based tests (hypothesis) of every parser of input from outside: run configurations,
AT2 records, register maps, Modbus values and replies, CANopen frames, URLs, fault SPECs and run records.
Each either accepts its input or refuses it with hsio's own error; nothing else escapes.
Bounded: the whole file runs in well under two minutes."""

from __future__ import annotations

import math
import socket
import struct
import time
import tomllib

import canopen
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hsio import config
from hsio.drivers import canopen as canopen_driver
from hsio.drivers import common, modbus_map
from hsio.drivers.modbus import parse_options as modbus_options
from hsio.emulators import faults
from hsio.errors import ConfigError, HsioError, ImplausibleMeasurementError, RecordError
from hsio.ground_motion import read_at2
from hsio.interfaces import Limits

FAST = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
SLOW = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])

scalars = st.one_of(st.none(), st.booleans(), st.integers(-10**12, 10**12), st.floats(allow_nan=True),
                    st.text(max_size=12))
keys = st.sampled_from([k for t in config.DEFAULTS.values() for k in t] + ["x", "rate ", ""])
tables = st.sampled_from(list(config.DEFAULTS) + list(config.FREE_TABLES) + ["nope"])
config_dicts = st.dictionaries(tables, st.one_of(scalars, st.dictionaries(keys, scalars, max_size=4)), max_size=4)


@FAST
@given(config_dicts)
def test_run_config_from_dict_accepts_or_names_the_problem(data):
    try:
        cfg = config.from_dict(data)
    except ConfigError as exc:
        assert str(exc).startswith("<dict>")
        return
    for (table, key), (low, high, _) in config.BOUNDS.items():
        assert low <= cfg[table][key] <= high


@FAST
@given(st.binary(max_size=300))
def test_run_config_file_of_any_bytes(tmp_path_factory, data):
    path = tmp_path_factory.mktemp("cfg") / "c.toml"
    path.write_bytes(data)
    try:
        config.load(path)
    except ConfigError as exc:
        assert str(path) in str(exc) or "<" not in str(exc)


toml_values = st.one_of(st.integers(-10**20, 10**20).map(str), st.floats(allow_nan=True, allow_infinity=True).map(
    lambda f: "nan" if math.isnan(f) else ("inf" if f > 0 else "-inf") if math.isinf(f) else repr(f)),
    st.sampled_from(["true", "false", '"x"', "[]", "{}", '"1e9"']))


@FAST
@given(st.sampled_from([(t, k) for t, ks in config.DEFAULTS.items() for k in ks]), toml_values)
def test_run_config_one_key_any_value(tmp_path_factory, table_key, value):
    table, key = table_key
    path = tmp_path_factory.mktemp("cfg") / "c.toml"
    path.write_text(f"[{table}]\n{key} = {value}\n")
    try:
        config.load(path)
    except ConfigError as exc:
        assert str(path) in str(exc)


numbers = st.one_of(st.floats(allow_nan=True, allow_infinity=True).map(repr), st.integers(-10**6, 10**9).map(str),
                    st.sampled_from(["NaN", "1e309", "-.", "0x10", "", "1,0"]))


@FAST
@given(st.one_of(st.integers(-5, 10**10).map(str), numbers), numbers, st.lists(numbers, max_size=30),
       st.sampled_from(["NPTS= {n}, DT= {dt} SEC", "{n}  {dt}  NPTS, DT", "NPTS={n},DT={dt}", "{n} {dt}"]))
def test_at2_reader(tmp_path_factory, npts, dt, values, header):
    path = tmp_path_factory.mktemp("at2") / "r.AT2"
    lines = ["PEER", "title", "G", header.format(n=npts, dt=dt)] + [" ".join(values[i:i + 5]) for i in range(0, len(values), 5)]
    path.write_text("\n".join(lines) + "\n")
    try:
        g = read_at2(path)
    except RecordError as exc:
        assert "r.AT2" in str(exc)
        return
    assert 2 <= g.accel_g.size and 1e-5 <= g.dt <= 1.0 and all(math.isfinite(x) for x in g.accel_g)


@FAST
@given(st.binary(max_size=400))
def test_at2_any_bytes(tmp_path_factory, data):
    path = tmp_path_factory.mktemp("at2") / "b.AT2"
    path.write_bytes(data)
    with pytest.raises(RecordError):
        g = read_at2(path)
        if g is not None:  # a valid record made of random bytes is fine too
            raise RecordError("valid")


DEFAULT_MAP = tomllib.loads(modbus_map.DEFAULT_MAP.read_text())
map_paths = st.sampled_from([("map", k) for k in ("device_id", "max_axes", "readwrite", "word_order", "name")]
                            + [("status_bits", k) for k in modbus_map.STATUS_BITS]
                            + [("command", "base"), ("command", "stride"), ("status", "base"), ("status", "stride"),
                               ("modes", "force"), ("lockstep", "advance"), ("reset", "interlock"), ("info", "rate_hz"),
                               ("command", "watchdog"), ("status", "sequence")])
map_values = st.one_of(st.integers(-3, 70000), st.booleans(), st.text(max_size=6), st.floats(allow_nan=True),
                       st.dictionaries(st.sampled_from(["address", "offset", "type", "scale", "bogus"]),
                                       st.one_of(st.integers(-2, 70000), st.sampled_from(["float32", "int16", "u8"]),
                                                 st.floats(allow_nan=True)), max_size=3))


@FAST
@given(st.lists(st.tuples(map_paths, map_values), min_size=1, max_size=3))
def test_register_map_mutations(changes):
    data = {k: dict(v) if isinstance(v, dict) else v for k, v in DEFAULT_MAP.items()}
    for (table, key), value in changes:
        data[table] = dict(data.get(table, {}))
        data[table][key] = value
    try:
        m = modbus_map.from_dict(data, "m.toml")
    except ConfigError as exc:
        assert str(exc).startswith("m.toml")
        return
    # a map that loads is usable: distinct bits, one axis fits a request, words encode and decode
    assert len(set(m.bits.values())) == len(m.bits)
    m.check_spans(1)
    assert isinstance(m.readwrite, bool) and 1 <= m.device_id <= 247
    words = m.pack_commands([{"displacement": 1.5, "force": -2.0, "mode": 0.0, "enable": 1.0, "watchdog": 3.0}], None,
                            m.command_span(1, False))
    assert all(0 <= w <= 0xFFFF for w in words)


@FAST
@given(st.sampled_from(list(modbus_map.TYPES)), st.sampled_from(["big", "little"]),
       st.floats(allow_nan=False, allow_infinity=False, min_value=-1e6, max_value=1e6), st.sampled_from([1.0, 10.0, 1000.0]))
def test_register_encode_decode_round_trip(kind, order, value, scale):
    reg = modbus_map.Register("x", 0, kind, scale)
    try:
        words = reg.encode(value, order)
    except ValueError:
        return  # does not fit the type: refused, never wrapped
    back = reg.decode(words, order)
    if kind == "float32":
        assert back == pytest.approx(value, rel=1e-6, abs=1e-6 / scale)
    else:
        assert back == pytest.approx(round(value * scale) / scale)


@FAST
@given(st.lists(st.integers(0, 0xFFFF), min_size=64, max_size=64))
def test_status_reply_of_any_words_never_reaches_the_integrator_implausible(words):
    m = modbus_map.load()
    status = m.unpack_status(words, 8)
    limits = Limits(254.0, 250.0, 500.0)
    for k, st_ in enumerate(status):
        check = common.Plausibility(f"axis {k}", limits, 1 / 1024)
        try:
            check.check(st_["displacement"], st_["force"], 0.0)
        except ImplausibleMeasurementError:
            continue
        assert math.isfinite(st_["displacement"]) and abs(st_["displacement"]) <= 254.0
        assert math.isfinite(st_["force"]) and abs(st_["force"]) <= 500.0


@FAST
@given(st.lists(st.tuples(st.floats(allow_nan=True, allow_infinity=True, width=32),
                          st.floats(allow_nan=True, allow_infinity=True, width=32)), min_size=1, max_size=40))
def test_plausibility_passes_only_plausible_sequences(samples):
    limits = Limits(254.0, 250.0, 500.0)
    check = common.Plausibility("a", limits, 1 / 1024)
    last = None
    for k, (d, f) in enumerate(samples):
        try:
            check.check(d, f, k / 1024)
        except ImplausibleMeasurementError:
            return
        assert math.isfinite(d) and math.isfinite(f) and abs(d) <= 254 and abs(f) <= 500
        if last is not None:
            assert abs(d - last[0]) <= 2 * 500 / 1024 + 2.0 + 1e-9 and abs(f - last[1]) <= 125.0
        last = (d, f)


url_text = st.one_of(
    st.text(max_size=40),
    st.builds(lambda s, h, p, q: f"{s}://{h}:{p}{q}", st.sampled_from(["modbus+tcp", "modbus+rtu", "canopen+virtual",
                                                                        "canopen+slcan", "x"]),
              st.sampled_from(["127.0.0.1", "", "[::1]", "h st", "%00"]), st.one_of(st.integers(-5, 10**6).map(str),
                                                                                  st.text(max_size=5)),
              st.sampled_from(["", "/1", "/dev/pts/3/2", "?timeout_s=nan", "?retries=1e9", "?map=", "?x=1", "/0", "/999"])))


@FAST
@given(url_text)
def test_urls_parse_or_refuse(url):
    try:
        if url.startswith("canopen"):
            canopen_driver.parse_url(url, {})
        else:
            opts = modbus_options(url, {})
            common.url_port(url, 502)
            assert 0 < opts["timeout_s"] <= 60
    except ConfigError:
        pass


@FAST
@given(st.text(alphabet=st.sampled_from(list("dropelaycrutsknvi@:,=0123456789.+-x ")), max_size=60))
def test_fault_spec_parses_or_is_refused(spec):
    try:
        schedule = faults.parse(spec)
    except ConfigError as exc:
        assert "--faults" in str(exc)
        return
    assert all(f.kind in faults.KINDS and f.tick >= 0 for f in schedule.faults)
    assert len(schedule.faults) <= faults.MAX_FAULTS


# -- frames on the wire: random bytes at a live emulator, which keeps answering ---------------------

@pytest.fixture(scope="module")
def modbus_emulator():
    from hsio.commands.emulate import bank_from_config
    from hsio.emulators.modbus import ModbusEmulator

    emu = ModbusEmulator(bank_from_config(None, lockstep=True, watchdog_s=0.0), modbus_map.load()).start()
    yield emu
    emu.stop()


def _still_answers(port: int) -> None:
    from pymodbus.client import ModbusTcpClient

    client = ModbusTcpClient("127.0.0.1", port=port, timeout=1.0, retries=1)
    assert client.connect()
    try:
        rr = client.read_holding_registers(0, count=2, device_id=1)
        assert not rr.isError() and rr.registers == [16256, 0]  # map_version 1.0
    finally:
        client.close()


mbap_frames = st.builds(
    lambda tid, unit, pdu: struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu,
    st.integers(0, 0xFFFF), st.sampled_from([0, 1, 2, 255]),
    st.one_of(st.binary(max_size=40),
              st.builds(lambda fc, a, n: struct.pack(">BHH", fc, a, n), st.sampled_from([3, 6, 16, 23, 43, 99]),
                        st.integers(0, 0xFFFF), st.integers(0, 0xFFFF))))


@SLOW
@given(st.lists(st.one_of(mbap_frames, st.binary(max_size=60)), min_size=1, max_size=4))
def test_modbus_emulator_survives_any_frames(modbus_emulator, frames):
    with socket.create_connection(("127.0.0.1", modbus_emulator.port), timeout=1.0) as s:
        for frame in frames:
            s.sendall(frame)
        s.settimeout(0.02)
        try:
            s.recv(4096)
        except OSError:
            pass
    _still_answers(modbus_emulator.port)


@pytest.fixture(scope="module")
def canopen_pair():
    import canopen

    from hsio.commands.emulate import bank_from_config
    from hsio.emulators.canopen import CanopenEmulator

    emu = CanopenEmulator(bank_from_config(None, lockstep=True, watchdog_s=0.0), "fuzz", 1).start()
    net = canopen.Network()
    net.connect(interface="virtual", channel="fuzz")
    node = canopen.RemoteNode(1, canopen_driver.cod.object_dictionary(1))
    net.add_node(node)
    node.sdo.RESPONSE_TIMEOUT = 1.0
    for axis in emu.axes:
        axis.node.nmt.state = "OPERATIONAL"  # PDOs count only in OPERATIONAL
    yield emu, net, node
    net.disconnect()
    emu.stop()


@SLOW
@given(st.lists(st.tuples(st.sampled_from([0x80, 0x201, 0x301, 0x601, 0x000, 0x701]), st.binary(max_size=8)),
                min_size=1, max_size=6))
def test_canopen_emulator_survives_any_frames(canopen_pair, frames):
    emu, net, node = canopen_pair
    for cob, data in frames:
        if cob == 0x000 and data[:1] in (b"\x02", b"\x80", b"\x81", b"\x82"):
            continue  # NMT stop / pre-operational / reset: legitimate commands, not garbage
        net.send_message(cob, data)
    time.sleep(0.002)
    # Garbage on the SDO channel may leave a transfer half open, and each garbage request may be
    # answered by an abort that arrives late, while a read is waiting: a read can be aborted once
    # per such frame (and once more for the half-open transfer it ends); the read after them is
    # answered.
    for _ in range(sum(cob == 0x601 for cob, _ in frames) + 1):
        try:
            value = node.sdo[0x1000].raw
            break
        except canopen.SdoAbortedError:
            continue
    else:
        value = node.sdo[0x1000].raw
    assert value == canopen_driver.cod.DEVICE_TYPE_402
    for axis in emu.axes:
        axis.node.nmt.state = "OPERATIONAL"


@FAST
@given(st.binary(max_size=8))
def test_canopen_driver_tpdo_of_any_bytes(data):
    """A TPDO2 of any content is either taken (a full frame) or logged and ignored: no exception."""
    import canopen

    od = canopen_driver.cod.object_dictionary(1)
    node = canopen.RemoteNode(1, od)
    canopen.Network().add_node(node)  # not connected: the maps only need somewhere to subscribe
    node.tpdo.read(from_od=True)
    drive = canopen_driver.DriveNode.__new__(canopen_driver.DriveNode)
    drive.id, drive.actual, drive.received = 1, (0, 0, 0), __import__("threading").Event()
    drive.rpdo2, drive.tpdo2, drive.cycle_mapped = node.rpdo[2], node.tpdo[2], True
    drive.expected_cycle, drive.stale = None, 0  # not in lockstep: any full frame is an answer
    drive.cycle_lock = __import__("threading").Lock()
    drive.tpdo2.data = bytearray(data)
    drive.on_tpdo2(drive.tpdo2)
    assert drive.received.is_set() == (len(data) >= 8)


class ReplyServer:
    """A TCP 'controller' whose reply to every request is the next of a list of byte strings
    (hypothesis draws them): garbage, wrong lengths, wrong transaction ids, exception replies."""

    def __init__(self):
        import threading

        self.replies: list[bytes] = []
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(8)
        self.sock.settimeout(0.05)
        self.port = self.sock.getsockname()[1]
        self.stop = threading.Event()
        threading.Thread(target=self._run, daemon=True).start()

    def _run(self):
        while not self.stop.is_set():
            try:
                conn, _ = self.sock.accept()
            except OSError:
                continue
            conn.settimeout(0.3)
            with conn:
                while not self.stop.is_set():
                    try:
                        request = conn.recv(4096)
                    except OSError:
                        break
                    if not request:
                        break
                    reply = self.replies.pop(0) if self.replies else b""
                    if reply:
                        # keep the request's transaction id half the time, so pymodbus parses further
                        if len(reply) > 2 and reply[0] & 1:
                            reply = request[:2] + reply[2:]
                        try:
                            conn.sendall(reply)
                        except OSError:
                            break

    def close(self):
        self.stop.set()
        self.sock.close()


@pytest.fixture(scope="module")
def reply_server():
    s = ReplyServer()
    yield s
    s.close()


replies = st.one_of(
    st.binary(max_size=40),
    st.builds(lambda fc, body: struct.pack(">HHHBB", 0, 0, len(body) + 2, 1, fc) + body,
              st.sampled_from([3, 23, 0x83, 0x97, 16, 1]), st.binary(max_size=30)),
    st.builds(lambda n, words: struct.pack(">HHHBBB", 0, 0, 3 + 2 * len(words), 1, 3, n)
              + b"".join(struct.pack(">H", w) for w in words), st.integers(0, 255),
              st.lists(st.integers(0, 0xFFFF), max_size=12)),
)


@SLOW
@given(st.lists(replies, min_size=1, max_size=3))
def test_modbus_driver_given_any_replies(reply_server, answers):
    """Whatever a 'controller' answers, the driver reads a value it can check, or raises
    hsio's CommunicationError (or a refusal it can name): nothing else escapes."""
    from hsio.drivers.modbus import ModbusLink

    reply_server.replies = list(answers)
    link = ModbusLink(f"modbus+tcp://127.0.0.1:{reply_server.port}", 1,
                      {"timeout_s": 0.05, "retries": 1, "reconnect_delay_s": 0.0})
    try:
        link._connect()
        link.read_status()
        assert len(link.status) == 1
    except HsioError:
        pass
    finally:
        link.close()


@pytest.fixture(scope="module")
def recorded_run(tmp_path_factory):
    """A short lockstep run's record, with its controller samples."""
    from hsio import runner

    out = tmp_path_factory.mktemp("record") / "run"
    runner.run(config.from_dict({"record": {"duration_s": 0.1}, "output": {"plots": False}}), out)
    return out / "run.sqlite"


json_values = st.one_of(scalars, st.lists(st.one_of(st.text(max_size=4), st.integers()), max_size=3),
                        st.dictionaries(st.text(max_size=4), scalars, max_size=2))
record_edits = st.one_of(
    st.tuples(st.just("meta"), st.sampled_from(["dof_names", "actuator_names", "config", "dt", "emulator_settings"]),
              json_values),
    st.tuples(st.just("steps"), st.sampled_from(["step", "u_C1", "disp_C2", "force_C1", "time_s", "mode_C1"]), scalars),
    st.tuples(st.just("samples"), st.sampled_from(["step", "k", "cmd_C1", "disp_C1", "force_C2"]), scalars),
    st.tuples(st.just("drop"), st.sampled_from(["meta", "summary", "steps", "samples", "events", "ns"]), st.none()))


@FAST
@given(st.lists(record_edits, min_size=1, max_size=3))
def test_a_run_record_is_read_whole_or_named_as_damaged(tmp_path_factory, recorded_run, edits):
    """run.sqlite as `hsio diagnose`, `hsio resume` and notebooks read it back (hsio.recording.Run
    and the diagnose reader of an actuator's samples): any edit of its meta, steps, samples or
    tables is read or refused with hsio's own error."""
    import json
    import sqlite3

    from hsio.diagnose.readers import read_run
    from hsio.recording import Run

    path = tmp_path_factory.mktemp("run") / "run.sqlite"
    path.write_bytes(recorded_run.read_bytes())
    with sqlite3.connect(path) as db:
        for where, key, value in edits:
            try:
                if where == "meta":
                    db.execute("UPDATE meta SET value = ? WHERE key = ?", (json.dumps(value), key))
                elif where == "drop":
                    db.execute(f"DROP TABLE IF EXISTS {key}")
                else:
                    value = value if not isinstance(value, float) or math.isfinite(value) else str(value)
                    db.execute(f"UPDATE {where} SET {key} = ? WHERE rowid % 3 = 0", (value,))
            except sqlite3.Error:
                pass  # an edit SQLite itself refuses (a step that is not an integer): the record as it was
    try:
        run = Run(path)
        run.events(), run.table("compensation")
        read_run(path)
    except (HsioError, RecordError):
        pass
