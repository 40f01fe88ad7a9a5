"""SDO exchanges with a drive that answers a request twice, late (python-can's virtual bus): the
late duplicate is dropped, never read as the answer to the next request (drivers/canopen_sdo.py)."""

from __future__ import annotations

import itertools
import struct

import pytest
from canopen.objectdictionary import ODVariable, VISIBLE_STRING

from hsio.commands.emulate import bank_from_config
from hsio.drivers import canopen_od as cod
from hsio.drivers.canopen import CanopenLink
from hsio.drivers.canopen_sdo import MatchingSdoClient
from hsio.emulators.canopen import CanopenEmulator
from hsio.errors import CommunicationError, SdoAbortError
from wire import write_config

_channels = itertools.count()
TIMEOUT_S = 0.3  # each unanswered attempt costs this much; a loaded host answers well within it


class AnswersTwiceLate:
    """The emulated node's SDO server, answering the first request for ``mux`` (index, subindex)
    twice, late: the first copy is answered only once the client has sent it again (its answer
    arrives after the client's timeout), and the second answer goes out when the next request
    arrives, just before that request's own answer."""

    def __init__(self, emu: CanopenEmulator, mux: tuple[int, int], axis: int = 0):
        self.server = emu.axes[axis].node.sdo
        self.network = emu.network
        self.mux = mux
        self.copies = 0  # copies of the request for mux received
        self.held: bytes | None = None
        self.last: bytes | None = None
        send = self.server.send_response

        def capture(response):
            self.last = bytes(response)
            send(response)

        self.server.send_response = capture
        self.network.unsubscribe(self.server.rx_cobid, self.server.on_request)
        self.network.subscribe(self.server.rx_cobid, self.on_request)

    def on_request(self, can_id, data, timestamp):
        initiate = data[0] >> 5 in (1, 2)  # initiate download, upload
        if initiate and struct.unpack_from("<HB", data, 1) == self.mux and self.held is None and self.copies < 2:
            self.copies += 1
            if self.copies == 2:  # the client's resend: answer now, and once more later
                self.server.on_request(can_id, data, timestamp)
                self.held = self.last
            return
        if self.held is not None:
            self.network.send_message(self.server.tx_cobid, self.held)
            self.held = None
        self.server.on_request(can_id, data, timestamp)


@pytest.fixture
def node(tmp_path):
    """The emulated drive (one axis) and a link to it, identified, nothing enabled."""
    emu = CanopenEmulator(bank_from_config(write_config(tmp_path), lockstep=True), f"hsio-sdo-{next(_channels)}").start()
    link = CanopenLink(emu.url, 1, {"timeout_s": TIMEOUT_S, "retries": 2})
    try:
        link.open(enable=False)
        yield emu, link, link.drives[0]
    finally:
        link.close()
        emu.stop()


def test_a_late_duplicate_write_response_is_not_read_as_the_next_read_s_answer(node):
    """The start-up's heartbeat write answered twice: the statusword read after it gets the
    statusword (canopen alone read the write's duplicate: "Unexpected response 0x60")."""
    emu, link, d = node
    server = AnswersTwiceLate(emu, (0x1017, 0))
    d.sdo_write(0x1017, 250, "producer heartbeat time")
    assert server.copies == 2 and server.held is not None  # answered late, the duplicate still to come
    assert d.sdo_read(0x6041, what="statusword") == emu.axes[0].statusword()
    assert server.held is None and d.node.sdo.discarded == 1
    assert struct.unpack("<H", emu.axes[0].node.data_store[0x1017][0])[0] == 250


def test_a_late_duplicate_read_response_is_not_read_as_another_object_s_value(node):
    emu, link, d = node
    AnswersTwiceLate(emu, (0x6076, 0))
    assert d.sdo_read(0x6076, what="rated torque") == cod.RATED_FORCE_N
    rated_counts = d.sdo_read(0x607D, 2, "max position limit")
    assert rated_counts == struct.unpack("<i", emu.axes[0].node.data_store[0x607D][2])[0]
    assert d.node.sdo.discarded == 1


def test_a_late_duplicate_abort_does_not_make_the_next_object_look_missing(node):
    """An optional object's read aborts (the drive lacks it) and the abort comes twice: the next
    optional object is still read, not taken as missing."""
    emu, link, d = node
    AnswersTwiceLate(emu, (0x5000, 0))
    assert link._read_optional(d, 0x5000, 0, "an object it does not have") is None
    assert link._read_optional(d, 0x6072, 0, "max torque") == d.max_torque_permille > 0
    assert d.node.sdo.discarded == 1


def test_segmented_transfers_after_a_late_duplicate_carry_the_whole_value(node):
    """Segment responses carry no multiplexer: their toggle bit is what is checked."""
    emu, link, d = node
    od = emu.axes[0].node.object_dictionary
    name = ODVariable("manufacturer device name", 0x1008, 0)
    name.data_type, name.access_type = VISIBLE_STRING, "rw"
    od.add_object(name)
    emu.axes[0].node.data_store[0x1008] = {0: b"hsio emulated CiA 402 drive"}
    AnswersTwiceLate(emu, (0x1017, 0))
    d.sdo_write(0x1017, 100, "producer heartbeat time")
    assert d.node.sdo.upload(0x1008, 0) == b"hsio emulated CiA 402 drive"
    d.node.sdo.download(0x1008, 0, b"a name longer than seven bytes")
    assert d.node.sdo.upload(0x1008, 0) == b"a name longer than seven bytes"
    assert d.node.sdo.discarded == 1


def test_the_answer_check_by_kind_multiplexer_and_toggle():
    client = MatchingSdoClient(0x601, 0x581, cod.object_dictionary(1))

    def frame(command: int, index: int = 0, sub: int = 0) -> bytes:
        return struct.pack("<BHB4x", command, index, sub)

    client.expected = (2, 0, (0x6041, 0), 2)  # an initiate upload of 0x6041:0
    assert client.answers(frame(0x4B, 0x6041, 0))
    assert not client.answers(frame(0x4B, 0x6064, 0))  # another object's value
    assert not client.answers(frame(0x60, 0x6041, 0))  # a download response
    assert client.answers(frame(0x80, 0x6041, 0)) and client.answers(frame(0x80))  # its abort, one without multiplexer
    assert not client.answers(frame(0x80, 0x5000, 0))  # another request's abort
    client.expected = (0, 0x10, (0x1008, 0), 3)  # the segment upload with toggle 1 of 0x1008:0
    assert client.answers(frame(0x10, 0x6841, 0x6F))  # a segment: data where a multiplexer would be
    assert not client.answers(frame(0x00, 0x6841, 0x6F))  # the segment before (toggle 0)
    assert not client.answers(frame(0x4B, 0x1008, 0))  # the initiate's duplicate
    assert client.answers(frame(0x80, 0x1008, 0)) and not client.answers(frame(0x80, 0x1017, 0))
    client.expected = None  # no request in flight: canopen's own handling
    assert client.answers(frame(0x60, 0x1017, 0))


def test_retries_zero_sends_an_sdo_request_once(tmp_path):
    """[driver] retries counts the requests sent again after the first (docs/canopen.md): with 0
    the drive sees one copy, and its silence is an error naming the object."""
    emu = CanopenEmulator(bank_from_config(write_config(tmp_path), lockstep=True), f"hsio-sdo-{next(_channels)}").start()
    link = CanopenLink(emu.url, 1, {"timeout_s": TIMEOUT_S, "retries": 0})
    try:
        link.open(enable=False)
        server = AnswersTwiceLate(emu, (0x6076, 0))
        with pytest.raises(CommunicationError, match=r"node 1: SDO read of .*0x6076:0.* failed") as err:
            link.drives[0].sdo_read(0x6076, what="rated torque")
        assert not isinstance(err.value, SdoAbortError)
        assert server.copies == 1
    finally:
        link.close()
        emu.stop()
