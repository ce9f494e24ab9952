"""Dating synchronous TPDOs by the SYNC they answer, without a counter in the PDO (``[bench] timebase = "sync"``).

A CiA 402 drive samples a synchronous TPDO (transmission type 1) at each SYNC and sends it after that SYNC. The
host produces the SYNCs, so it knows when it sent each one and for which of its ticks; ``SyncMatcher`` gives each
TPDO the tick of the SYNC it answers from two facts only: the order of the frames and their times on one clock
(the time each SYNC was handed to the bus, ``time.time()``, and the receive time python-can stamps each frame
with, which its interfaces give on the same epoch clock).

The rules, for a TPDO received at time t, where L is the latest SYNC sent at or before t:

- it answers L or, sent late, L - 1 (a TPDO is never later than the next SYNC's own TPDO: a drive sends them in
  order); SYNCs before L - 1 that got no answer are gaps (counted in ``lost``);
- when L - 1 has an answer already (or L is the first SYNC), it answers L;
- when neither L - 1 nor L has one, it is late for L - 1 or L - 1's TPDO was lost: it is held until the next
  TPDO tells. A next TPDO that also follows L (no SYNC between them) means the held one was L - 1's (late) and
  the next one L's, provided L - 2 has an answer (else the two may be L - 2's and L - 1's, from a drive that fell
  behind: both are dropped); a next TPDO after a later SYNC leaves the held one undecided: it is dropped and
  counted (``ambiguous``), and L - 1 and L are gaps. A sample is never given a SYNC it might not answer;
- a TPDO with no SYNC left to answer (received before any SYNC, or a second answer to L) is dropped and counted
  (``unmatched``).

The SYNCs remembered are the latest ``memory``; a TPDO older than all of them is unmatched.
"""

from __future__ import annotations

from typing import Generic, TypeVar

__all__ = ["SyncMatcher"]

T = TypeVar("T")


class SyncMatcher(Generic[T]):
    """Matches TPDOs (any item, with its receive time) to host-produced SYNCs (module docstring). Pure: no I/O, no
    clock of its own; feed ``sent`` and ``received`` in the order the host sent and read the frames."""

    def __init__(self, memory: int = 4096) -> None:
        """``memory``: how many of the latest SYNCs are remembered (at least 2)."""
        if memory < 2:
            raise ValueError(f"SyncMatcher memory must be at least 2 SYNCs, got {memory!r}")
        self.memory = memory
        self._ticks = [0] * memory
        self._times = [0.0] * memory
        self._sent = 0  # SYNCs sent; SYNC n (0-based) is at n % memory
        self._done = -1  # the latest SYNC answered or given up: later TPDOs answer only later ones
        self._held: tuple[int, float, T] | None = None  # (L, receive time, item) of a TPDO that may answer L-1 or L
        self.matched = 0
        """TPDOs given a SYNC."""
        self.lost = 0
        """SYNCs that got no answer (a TPDO lost, or a SYNC the drive missed), counted when a later one is answered."""
        self.ambiguous = 0
        """TPDOs dropped because they answer one of two SYNCs and nothing tells which."""
        self.unmatched = 0
        """TPDOs dropped because no SYNC is left for them to answer."""

    def sent(self, tick: int, time_s: float) -> None:
        """A SYNC went out for host tick ``tick`` at ``time_s`` (s, the clock received frames are stamped with,
        taken just before the send)."""
        at = self._sent % self.memory
        self._ticks[at] = tick
        self._times[at] = time_s
        self._sent += 1

    def received(self, time_s: float, item: T) -> list[tuple[int, T]]:
        """A TPDO (``item``) received at ``time_s``: the (tick, item) pairs this decides, oldest first (none, this
        one, or a held one and this one)."""
        latest = self._latest_before(time_s)
        out: list[tuple[int, T]] = []
        held, self._held = self._held, None
        if held is not None:
            at, _, earlier = held
            if latest == at:
                if at - 2 <= self._done or at - 2 < self._oldest:
                    # two TPDOs after the same SYNC: the first was the one before's, sent late
                    out.append(self._give(at - 1, earlier))
                    out.append(self._give(at, item))
                    return out
                # the SYNC before those is unanswered too: the two may answer it and the next (a drive that fell
                # two SYNCs behind), so neither is dated
                self.ambiguous += 2
                self._give_up(at)
                return out
            self.ambiguous += 1
            self._give_up(at)
        if latest is None or latest <= self._done:
            self.unmatched += 1
            return out
        if latest - 1 <= self._done or latest == self._oldest:
            out.append(self._give(latest, item))
        else:
            self._held = (latest, time_s, item)
        return out

    @property
    def held(self) -> bool:
        """Whether a TPDO waits for the next one to tell which SYNC it answers."""
        return self._held is not None

    @property
    def _oldest(self) -> int:
        """The oldest SYNC remembered."""
        return max(0, self._sent - self.memory)

    def _latest_before(self, time_s: float) -> int | None:
        """The number of the latest remembered SYNC sent at or before ``time_s``; None when there is none."""
        n = self._sent - 1
        while n >= self._oldest:
            if self._times[n % self.memory] <= time_s:
                return n
            n -= 1
        return None

    def _give(self, n: int, item: T) -> tuple[int, T]:
        """SYNC ``n`` answered by ``item``; the SYNCs skipped since the last answered one are gaps."""
        self.lost += max(0, n - self._done - 1)
        self._done = n
        self.matched += 1
        return self._ticks[n % self.memory], item

    def _give_up(self, n: int) -> None:
        """SYNCs up to ``n`` get no answer."""
        if n > self._done:
            self.lost += n - self._done
            self._done = n
