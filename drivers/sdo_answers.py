"""An SDO client that takes as the answer to a request only a response about the same object.

canopen's ``SdoClient`` reads the next response in its queue as the answer to the request it just sent. A drive
that answers after the request timed out (a busy drive, a slow gateway) leaves that answer to be read by the next
request: a write of the controlword then fails with "Unexpected response 0x4B" (the late answer to a read), and
every request after it may be read one answer off. CiA 301's responses to an initiate request (upload, download)
and its aborts carry the object's index and subindex, so a response naming another object is a late one, dropped
and counted (``late_answers``), and the wait goes on for the right one within ``RESPONSE_TIMEOUT``.
"""

from __future__ import annotations

import queue
import struct
import time

from canopen import RemoteNode
from canopen.sdo.client import SdoClient
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

__all__ = ["MatchingRemoteNode", "MatchingSdoClient"]

_INITIATE_REQUESTS = (1, 2)  # client command specifiers: initiate download, initiate upload
_NAMING_RESPONSES = (2, 3, 4)  # server command specifiers that carry the object: upload, download initiate; abort
_ABORT = 4


class MatchingSdoClient(SdoClient):
    """``canopen.sdo.SdoClient`` whose answers must name the object of the transfer under way (module docstring)."""

    def __init__(self, rx_cobid: int, tx_cobid: int, od: object) -> None:
        super().__init__(rx_cobid, tx_cobid, od)
        self._object: bytes | None = None  # index (little endian) and subindex of the transfer under way
        self.late_answers = 0
        """Responses dropped because they named another object (answers to earlier requests that timed out)."""

    def send_request(self, request: bytes | bytearray) -> None:
        if request[0] >> 5 in _INITIATE_REQUESTS:
            self._object = bytes(request[1:4])
        super().send_request(request)

    def read_response(self) -> bytes:
        deadline = time.monotonic() + self.RESPONSE_TIMEOUT
        while True:
            try:
                response: bytes = self.responses.get(block=True, timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                raise SdoCommunicationError("No SDO response received") from None
            specifier = response[0] >> 5
            named = bytes(response[1:4])
            if (specifier in _NAMING_RESPONSES and self._object is not None and named != self._object
                    and not (specifier == _ABORT and named == bytes(3))):
                self.late_answers += 1
                continue
            if specifier == _ABORT:
                (code,) = struct.unpack_from("<L", response, 4)
                raise SdoAbortedError(code)
            return response


class MatchingRemoteNode(RemoteNode):
    """``canopen.RemoteNode`` whose SDO channels are ``MatchingSdoClient`` (its PDO maps go through them too)."""

    def add_sdo(self, rx_cobid: int, tx_cobid: int) -> MatchingSdoClient:
        client = MatchingSdoClient(rx_cobid, tx_cobid, self.object_dictionary)
        self.sdo_channels.append(client)
        if self.has_network():
            self.network.subscribe(client.tx_cobid, client.on_response)
        return client
