"""Dating synchronous TPDOs by the SYNC they answer, without a counter in the PDO (``[bench] timebase = "sync"``).

A CiA 402 drive samples a synchronous TPDO (transmission type 1) at each SYNC and sends it after that SYNC. The
host produces the SYNCs, so it knows when it sent each one and for which of its ticks; ``SyncMatcher`` gives each
TPDO the tick of the SYNC it answers from two facts only: the order of the frames and their times on one clock
(the time each SYNC was handed to the bus, ``time.time()``, and the receive time python-can stamps each frame
with, which its interfaces give on the same epoch clock).

What it assumes of the drive: one TPDO at most for each SYNC, sent after that SYNC and in the order of the SYNCs
(a TPDO may be lost, and a drive may miss a SYNC and answer none). A TPDO received at time t then answers one of
the SYNCs sent before t that no earlier TPDO answered. The rules, with L the latest SYNC sent at or before t and
"pending" the SYNCs after the latest one decided, up to L:

- **By count (exact).** When the undecided TPDOs are as many as the pending SYNCs, every pending SYNC has its
  answer and the order gives each TPDO its SYNC: nothing else fits. This dates a TPDO late by any number of SYNCs
  once the drive has caught up, such as the burst of answers a drive sends after it stalled for several SYNCs.
- **By rhythm (after a gap).** While fewer TPDOs than pending SYNCs have come, a TPDO may be lost or still on its
  way, and nothing tells which until the drive settles into its rhythm again: ``steady`` TPDOs in a row, each the
  only one after its SYNC, each after the SYNC following the previous one's (one a SYNC, as a drive that keeps up
  sends them). The newest of those then answers L; the undecided ones before it are dropped (counted in
  ``ambiguous``) and the pending SYNCs before L are gaps (counted in ``lost``). A sample is never given a SYNC
  from a guess while a burst is still arriving; what this rule assumes is that a drive which sends one TPDO a
  SYNC, ``steady`` times in a row, is not behind.
- A TPDO with no SYNC left to answer (received before any SYNC, or a second answer to a decided SYNC) is dropped
  and counted (``unmatched``; the second kind also in ``extra``, below).
- A TPDO the same as the one before it (``same``, where given), with no SYNC sent between the two or received
  within a quarter of the time between the latest SYNCs after it, is dropped as a repeat (a frame received twice)
  and counted (``repeats``): counted as an answer it could fill the place of a lost one and date the TPDOs
  between a SYNC off. A drive's own answers to two SYNCs that happen to be equal, in a burst, are dropped with
  it: a gap, never a shift.

A gap dated by rhythm assumes the drive is not behind. A drive that is behind shows it the moment it catches up,
or a TPDO comes unasked: a TPDO received when every SYNC sent before it has its answer (counted in ``extra``)
contradicts the rule's guess, and the samples dated since the latest gap dated by rhythm (``rhythm_tick``) may be a
SYNC off. A drive that stays behind never catches up, so the host checks (``skip``): it sends no SYNC for one tick
(or sends it late) just after a SYNC whose answer has come. Until the next SYNC a drive that keeps up sends nothing;
one that answers more than a SYNC period late sends the answer to that SYNC now: an ``extra`` TPDO. A repeat of the
TPDO before (the same data) there leaves the check undecided (``checks_undecided``): a frame received twice and a
late answer with the same values look alike.

The SYNCs remembered are the latest ``memory``; a TPDO older than all of them is unmatched, and undecided TPDOs
whose pending SYNCs are forgotten are dropped.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import Generic, TypeVar

__all__ = ["STEADY", "SyncMatcher"]

T = TypeVar("T")

STEADY = 3
"""TPDOs in a row, one after each of consecutive SYNCs, that date the newest of them after a gap (the default)."""


class SyncMatcher(Generic[T]):
    """Matches TPDOs (any item, with its receive time) to host-produced SYNCs (module docstring). Pure: no I/O, no
    clock of its own; feed ``sent`` and ``received`` in the order the host sent and read the frames."""

    def __init__(self, memory: int = 4096, steady: int = STEADY, same: Callable[[T, T], bool] | None = None) -> None:
        """``memory``: how many of the latest SYNCs are remembered (at least 2). ``steady``: how many TPDOs in a
        row, one after each SYNC, date the newest of them after a gap (at least 2). ``same``: whether two TPDOs
        carry the same data (None: repeats are not looked for)."""
        if memory < 2:
            raise ValueError(f"SyncMatcher memory must be at least 2 SYNCs, got {memory!r}")
        if steady < 2:
            raise ValueError(f"SyncMatcher steady must be at least 2 TPDOs, got {steady!r}")
        self.memory = memory
        self.steady = steady
        self._ticks = [0] * memory
        self._times = [0.0] * memory
        self._sent = 0  # SYNCs sent; SYNC n (0-based) is at n % memory
        self._done = -1  # the latest SYNC answered or given up: later TPDOs answer only later ones
        self._held: list[T] = []  # TPDOs received since then, undecided, oldest first
        self._after: deque[int] = deque(maxlen=steady + 1)  # the latest SYNC before each of the last TPDOs taken
        self.matched = 0
        """TPDOs given a SYNC."""
        self.lost = 0
        """SYNCs that got no dated answer (a TPDO lost or dropped, or a SYNC the drive missed)."""
        self.ambiguous = 0
        """TPDOs dropped because they answer one of several SYNCs and nothing tells which."""
        self.unmatched = 0
        """TPDOs dropped because no SYNC is left for them to answer."""
        self.by_rhythm = 0
        """Gaps after which a TPDO was dated by the rhythm rule (a lost TPDO, or a drive fallen a SYNC behind: the
        rule cannot tell them apart)."""
        self.repeats = 0
        """TPDOs dropped as repeats of the one before (the same data, no SYNC sent between them)."""
        self.rhythm_tick: int | None = None
        """The tick of the SYNC the latest gap dated by rhythm ended at (None before the first)."""
        self.checks = 0
        """Checks made (``skip``): ticks the host sent no SYNC for, after a SYNC answered."""
        self.checks_undecided = 0
        """Checks in which a repeat of the TPDO before came (a frame received twice, or a late answer: ``skip``)."""
        self.extra = 0
        """TPDOs received when every SYNC sent before them had its answer: a drive that answered late (behind, and
        caught up, or found by a check), or a TPDO sent unasked (module docstring)."""
        self._same = same
        self._previous: tuple[int | None, float, T] | None = None  # (latest SYNC before, time, item): the last TPDO
        self._checking: int | None = None  # the SYNC after which the host sent none for a tick, while checked
        self._check_repeats = 0  # repeats received in the current check
        self._extra_before = 0  # ``extra`` when the current check began

    def sent(self, tick: int, time_s: float) -> None:
        """A SYNC went out for host tick ``tick`` at ``time_s`` (s, the clock received frames are stamped with,
        taken just before the send)."""
        at = self._sent % self.memory
        self._ticks[at] = tick
        self._times[at] = time_s
        self._sent += 1

    def received(self, time_s: float, item: T) -> list[tuple[int, T]]:
        """A TPDO (``item``) received at ``time_s``: the (tick, item) pairs this decides, oldest first (none, this
        one, or undecided ones and this one)."""
        latest = self._latest_before(time_s)
        checked = self._checking is not None and latest == self._checking  # received in a check's window
        if self._checking is not None and not checked and (latest is None or latest > self._checking):
            self._end_check()
        previous, self._previous = self._previous, (latest, time_s, item)
        if self._same is not None and previous is not None and self._same(previous[2], item) and (
                previous[0] == latest or time_s - previous[1] < 0.25 * self._interval()):
            self.repeats += 1
            self._check_repeats += checked
            return []
        if self._done + 1 < self._oldest:  # pending SYNCs forgotten: the undecided TPDOs cannot be dated
            self._drop_held()
            self._give_up(self._oldest - 1)
        if latest is None or latest <= self._done:
            self.unmatched += 1
            self.extra += latest is not None
            return []
        self._held.append(item)
        self._after.append(latest)
        if len(self._held) == latest - self._done:
            held, self._held = self._held, []
            return [self._give(self._done + 1, each) for each in held]
        if self._in_rhythm():
            self._held.pop()
            self._drop_held()
            self.by_rhythm += 1
            self.rhythm_tick = self._ticks[latest % self.memory]
            return [self._give(latest, item)]
        return []

    def skip(self) -> None:
        """The host sends no SYNC for one tick after the latest, which is answered (``settled``): a check that the
        drive answers within a SYNC period (module docstring). The TPDOs received before the next SYNC (by their
        times) are the check's; it ends with the first TPDO received after that SYNC."""
        if not self.settled:
            raise ValueError("SyncMatcher.skip: the latest SYNC has no answer yet")
        self._end_check()
        self._checking = self._sent - 1
        self._check_repeats = 0
        self._extra_before = self.extra
        self.checks += 1

    def _end_check(self) -> None:
        """The check under way (if any) is over: a TPDO after a later SYNC came, or another check begins."""
        if self._checking is not None:
            self.checks_undecided += self._check_repeats > 0 and self.extra == self._extra_before
            self._checking = None

    @property
    def checking(self) -> bool:
        """Whether a check (``skip``) is under way: no TPDO after the SYNC that followed it has come yet."""
        return self._checking is not None

    @property
    def settled(self) -> bool:
        """Whether the latest SYNC sent has its answer and no TPDO waits to be dated (a check may start)."""
        return self._sent > 0 and not self._held and self._done == self._sent - 1

    @property
    def held(self) -> bool:
        """Whether TPDOs wait for later ones to tell which SYNCs they answer."""
        return bool(self._held)

    @property
    def _oldest(self) -> int:
        """The oldest SYNC remembered."""
        return max(0, self._sent - self.memory)

    def _in_rhythm(self) -> bool:
        """Whether the last ``steady`` TPDOs came one after each of consecutive SYNCs, the first of them alone
        after its SYNC."""
        after = list(self._after)
        run = after[-self.steady:]
        if len(run) < self.steady or run != list(range(run[0], run[0] + self.steady)):
            return False
        return len(after) == len(run) or after[-self.steady - 1] < run[0]

    def _interval(self) -> float:
        """The time between the two latest SYNCs sent, s (0 before there are two)."""
        if self._sent < 2:
            return 0.0
        return self._times[(self._sent - 1) % self.memory] - self._times[(self._sent - 2) % self.memory]

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

    def _drop_held(self) -> None:
        """The undecided TPDOs are dropped."""
        self.ambiguous += len(self._held)
        self._held = []

    def _give_up(self, n: int) -> None:
        """SYNCs up to ``n`` get no answer."""
        if n > self._done:
            self.lost += n - self._done
            self._done = n
