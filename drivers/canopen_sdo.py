"""The SDO client of hsio's CANopen driver: canopen's SdoClient, taking only the answer to the
request in flight.

canopen sends a request again when its answer does not come within ``RESPONSE_TIMEOUT``
(``[driver] timeout_s``), up to ``MAX_RETRIES`` attempts in all (``retries`` + 1). When the first
answer was only late, the server answers both copies, and the second answer arrives after the
exchange it belonged to is over: read as the answer to the next request, it would be a wrong
value or an "unexpected response". Here a response is taken only if it answers the request in
flight; any other is dropped (and counted in :attr:`MatchingSdoClient.discarded`), and the wait
goes on within the same timeout:

* an initiate upload (read) is answered by an upload response, an initiate download (write) by
  a download response, each carrying the request's multiplexer (index, subindex);
* a segment request is answered by a segment response of the same kind with the request's
  toggle bit (a segment carries no multiplexer: the toggle tells a stale one);
* an abort answers any request when it carries the multiplexer of the transfer (the initiate's,
  for its segments), or none (0x0000:0, sent by servers that leave it out).

A duplicate answer to a request for the same object cannot be told from the answer to the next
one: it carries that object's value of a moment before. Block transfers (unused by hsio) pass as
canopen has them.
"""

from __future__ import annotations

import logging
import struct

from canopen.profiles.p402 import BaseNode402
from canopen.sdo import SdoClient

log = logging.getLogger(__name__)

# Command specifiers (CiA 301): the request's ccs and its response's scs, in the top 3 bits.
SEGMENT_DOWNLOAD, DOWNLOAD, UPLOAD, SEGMENT_UPLOAD, ABORT = 0, 1, 2, 3, 4
ANSWER = {DOWNLOAD: 3, UPLOAD: 2, SEGMENT_DOWNLOAD: 1, SEGMENT_UPLOAD: 0}  # request ccs -> response scs
TOGGLE = 0x10
NO_MULTIPLEXER = (0, 0)


def multiplexer(frame: bytes) -> tuple[int, int]:
    """(index, subindex) of an initiate or abort frame."""
    index, sub = struct.unpack_from("<HB", frame, 1)
    return index, sub


class MatchingSdoClient(SdoClient):
    """canopen's SdoClient that drops every response that does not answer the request in flight."""

    def __init__(self, rx_cobid, tx_cobid, od):
        super().__init__(rx_cobid, tx_cobid, od)
        self.expected: tuple[int, int, tuple[int, int], int] | None = None  # scs, toggle, multiplexer, ccs
        self.transfer = NO_MULTIPLEXER  # the multiplexer of the transfer under way (its initiate's)
        self.discarded = 0

    def request_response(self, sdo_request):
        """canopen's exchange (retries included), with the answer it may take set first: a
        response received from here on is checked before it is queued, and one queued before is
        cleared by canopen's exchange as it starts."""
        request = bytes(sdo_request)
        ccs = request[0] >> 5
        if ccs in ANSWER:
            if ccs in (DOWNLOAD, UPLOAD):
                self.transfer = multiplexer(request)
            self.expected = (ANSWER[ccs], request[0] & TOGGLE, self.transfer, ccs)
        else:
            self.expected = None
        try:
            return super().request_response(sdo_request)
        finally:
            self.expected = None

    def answers(self, response: bytes) -> bool:
        """Whether ``response`` answers the request in flight (always, when none is)."""
        expected = self.expected
        if expected is None:
            return True
        if len(response) < 8:
            return False
        scs, toggle, mux, ccs = expected
        kind = response[0] >> 5
        if kind == ABORT:
            return multiplexer(response) in (mux, NO_MULTIPLEXER)
        if kind != scs:
            return False
        if ccs in (DOWNLOAD, UPLOAD):
            return multiplexer(response) == mux
        return response[0] & TOGGLE == toggle

    def on_response(self, can_id, data, timestamp):
        response = bytes(data)
        if not self.answers(response):
            self.discarded += 1
            log.debug("SDO 0x%03X: response %s does not answer the request in flight: dropped", can_id, response.hex())
            return
        super().on_response(can_id, data, timestamp)


class MatchingNode402(BaseNode402):
    """canopen's CiA 402 node whose SDO channels are :class:`MatchingSdoClient`: its default
    channel, and the PDO maps and objects that read through it, use the matching client."""

    def add_sdo(self, rx_cobid, tx_cobid):
        client = MatchingSdoClient(rx_cobid, tx_cobid, self.object_dictionary)
        self.sdo_channels.append(client)
        if self.has_network():
            self.network.subscribe(client.tx_cobid, client.on_response)
        return client
