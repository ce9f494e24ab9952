"""An SDO client that takes as the answer to a request only a response about the same object.

canopen's ``SdoClient`` reads the next response in its queue as the answer to the request it just sent. A drive
that answers after the request timed out (a busy drive, a slow gateway) leaves that answer to be read by the next
request: a write of the controlword then fails with "Unexpected response 0x4B" (the late answer to a read), and
every request after it may be read one answer off. CiA 301's responses to an initiate request (upload, download)
and its aborts carry the object's index and subindex, so a response naming another object, or answering another
kind of request (a read's answer to a write), is a late one or a second copy of one: it is dropped and counted
(``late_answers``), and the wait goes on for the right one within ``RESPONSE_TIMEOUT``.
"""

from __future__ import annotations

import queue
import struct
import time

from canopen import RemoteNode
from canopen.sdo.client import SdoClient
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

__all__ = ["MatchingRemoteNode", "MatchingSdoClient", "NoSdoAnswer"]

_ANSWERS = {1: 3, 2: 2}  # client command specifier of an initiate request -> the server's (download 1 -> 3, upload 2)
_NAMING_RESPONSES = (2, 3, 4)  # server command specifiers that carry the object: upload, download initiate; abort
_ABORT = 4


class NoSdoAnswer(SdoCommunicationError):
    """No answer to the transfer under way came within ``RESPONSE_TIMEOUT`` (other SdoCommunicationErrors: an answer
    came that the transfer cannot take)."""


class MatchingSdoClient(SdoClient):
    """``canopen.sdo.SdoClient`` whose answers must name the object of the transfer under way (module docstring)."""

    def __init__(self, rx_cobid: int, tx_cobid: int, od: object) -> None:
        super().__init__(rx_cobid, tx_cobid, od)
        self._object: bytes | None = None  # index (little endian) and subindex of the transfer under way
        self._answer: int | None = None  # the server command specifier that answers its initiate request
        self.late_answers = 0
        """Responses dropped because they named another object or answered another kind of request (answers to
        earlier requests that timed out, or a second copy of one)."""

    def send_request(self, request: bytes | bytearray) -> None:
        answer = _ANSWERS.get(request[0] >> 5)
        if answer is not None:
            self._object, self._answer = bytes(request[1:4]), answer
        else:
            self._answer = None  # a segment: its answers name no object
        super().send_request(request)

    def read_response(self) -> bytes:
        deadline = time.monotonic() + self.RESPONSE_TIMEOUT
        while True:
            try:
                response: bytes = self.responses.get(block=True, timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                raise NoSdoAnswer("No SDO response received") from None
            specifier = response[0] >> 5
            named = bytes(response[1:4])
            if specifier == _ABORT:
                stale = self._object is not None and named not in (self._object, bytes(3))
            elif self._answer is not None:
                stale = specifier != self._answer or named != self._object
            else:
                stale = specifier in _NAMING_RESPONSES  # an initiate answer while segments are under way
            if stale:
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
