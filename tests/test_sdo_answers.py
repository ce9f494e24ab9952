"""SDO answers that come after their request timed out: the host's client (``drivers/sdo_answers.py``) against a
drive's SDO server written here from CiA 301's frame layout (raw frames on python-can's virtual bus), whose answers
are held back on request. A late answer must not be read as the answer to the next request."""

from __future__ import annotations

import struct
import threading
import time
import uuid
from collections.abc import Iterator

import can
import canopen
import pytest
from canopen.sdo import SdoAbortedError, SdoCommunicationError

from bodebench.drivers.sdo_answers import MatchingRemoteNode

NODE = 7
TIMEOUT_S = 0.2


class SlowServer:
    """Expedited SDO server of one node: 0x6041 (statusword) reads back 0x0200 | the last controlword written to
    0x6040; writes to 0x6060 are refused (abort). ``late`` answers are held back: each goes out when the next request
    has come, just before that request's own answer (a drive that answers after the host stopped waiting); with
    ``twice`` every answer goes out again then (a copy, as a gateway may repeat a frame); with ``silent`` it answers
    nothing."""

    def __init__(self, channel: str) -> None:
        self.bus = can.Bus(interface="virtual", channel=channel)
        self.late = 0
        self.twice = False
        self.silent = False
        self.controlword = 0
        self.requests: list[tuple[int, int, int]] = []  # (command, index, subindex)
        self._held: list[bytes] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _answer(self, command: int, index: int, subindex: int, data: bytes) -> bytes | None:
        if command >> 5 == 2 and index == 0x6041:  # initiate upload: 2 bytes, expedited
            return struct.pack("<BHBHxx", 0x4B, index, subindex, 0x0200 | self.controlword)
        if command >> 5 == 1 and index == 0x6060:
            return struct.pack("<BHBL", 0x80, index, subindex, 0x06090030)  # value range exceeded
        if command >> 5 == 1:  # initiate download, expedited
            if index == 0x6040:
                self.controlword = struct.unpack_from("<H", data, 4)[0]
            return struct.pack("<BHBxxxx", 0x60, index, subindex)
        return None  # the client's own abort of a transfer that timed out

    def _serve(self) -> None:
        while not self._stop.is_set():
            msg = self.bus.recv(0.02)
            if msg is None or msg.arbitration_id != 0x600 + NODE or self.silent:
                continue
            command, index, subindex = struct.unpack_from("<BHB", msg.data)
            answer = self._answer(command, index, subindex, bytes(msg.data))
            if answer is None:
                continue
            self.requests.append((command, index, subindex))
            if self.late:
                self.late -= 1
                self._held.append(answer)
                continue
            for data in [*self._held, answer]:
                self.bus.send(can.Message(arbitration_id=0x580 + NODE, data=data, is_extended_id=False))
            self._held = [answer] if self.twice else []  # its copy goes out when the next request has come

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.bus.shutdown()


@pytest.fixture
def bench() -> Iterator[tuple[SlowServer, MatchingRemoteNode]]:
    channel = f"sdo-{uuid.uuid4().hex[:8]}"
    server = SlowServer(channel)
    network = canopen.Network()
    network.connect(interface="virtual", channel=channel)
    node = MatchingRemoteNode(NODE, canopen.ObjectDictionary())
    node.sdo.RESPONSE_TIMEOUT = TIMEOUT_S
    network.add_node(node)
    try:
        yield server, node
    finally:
        network.disconnect()
        server.close()


def statusword(node: MatchingRemoteNode) -> int:
    return int.from_bytes(node.sdo.upload(0x6041, 0), "little")


def test_an_answer_after_its_request_timed_out_is_not_the_next_requests(bench: tuple[SlowServer,
                                                                                       MatchingRemoteNode]) -> None:
    server, node = bench
    assert statusword(node) == 0x0200
    server.late = 1
    with pytest.raises(SdoCommunicationError, match="No SDO response"):
        statusword(node)
    # the late answer to the read comes in after the write went out, before the write's own answer
    node.sdo.download(0x6040, 0, (0x0006).to_bytes(2, "little"))
    assert server.controlword == 0x0006
    assert statusword(node) == 0x0206
    assert node.sdo.late_answers == 1
    assert [r[1] for r in server.requests].count(0x6041) == 3


def test_a_late_answer_naming_the_same_object_is_taken(bench: tuple[SlowServer, MatchingRemoteNode]) -> None:
    # a read of the statusword that timed out, then the same read: the late answer is an answer about that object
    # (its value then) and is taken; the fresh one that follows is not read as the write's
    server, node = bench
    server.late = 1
    with pytest.raises(SdoCommunicationError):
        statusword(node)
    assert statusword(node) == 0x0200
    node.sdo.download(0x6040, 0, (0x000F).to_bytes(2, "little"))
    assert statusword(node) == 0x020F


def test_a_late_abort_of_another_object_is_dropped_and_the_right_one_raised(
        bench: tuple[SlowServer, MatchingRemoteNode]) -> None:
    server, node = bench
    server.late = 1
    with pytest.raises(SdoCommunicationError):
        node.sdo.download(0x6060, 0, b"\x08")
    node.sdo.download(0x6040, 0, (0x0007).to_bytes(2, "little"))  # the late abort of 0x6060 comes first
    assert server.controlword == 0x0007 and node.sdo.late_answers == 1
    with pytest.raises(SdoAbortedError) as info:
        node.sdo.download(0x6060, 0, b"\x08")
    assert info.value.code == 0x06090030


def test_no_answer_at_all_times_out(bench: tuple[SlowServer, MatchingRemoteNode]) -> None:
    server, node = bench
    server.silent = True
    start = time.monotonic()
    with pytest.raises(SdoCommunicationError, match="No SDO response"):
        statusword(node)
    assert time.monotonic() - start >= TIMEOUT_S


def test_a_second_copy_of_an_answer_is_not_the_next_requests(bench: tuple[SlowServer, MatchingRemoteNode]) -> None:
    # a read of the controlword's object, then a write of it: the read's answer comes again, about the same object,
    # after the write went out; it answers a read, not a write
    server, node = bench
    server.twice = True
    assert statusword(node) == 0x0200
    node.sdo.download(0x6041, 0, (0x0000).to_bytes(2, "little"))  # the copy of the read's answer comes first
    node.sdo.download(0x6040, 0, (0x0006).to_bytes(2, "little"))
    assert statusword(node) == 0x0206
    assert server.controlword == 0x0006 and node.sdo.late_answers == 3
