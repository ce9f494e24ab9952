"""Where an offline sweep's figures are drawn: processes forked from one that imported the plotting modules, so
that they are imported once (about 0.4 s of CPU a process, as much as drawing two figures).

:class:`ForkingDrawer` is a :class:`concurrent.futures.Executor`: ``submit(fn, *args)`` sends the call to the
drawing process, which runs it on a pool of forks of itself and passes the result, or the exception, back to the
future. Where processes cannot be forked (Windows, macOS' default start method) :func:`drawing_executor` gives a
process pool instead, each of its processes importing the modules.
"""

from __future__ import annotations

import functools
import importlib
import multiprocessing
import pickle
import signal
import threading
from collections.abc import Callable, Collection, Iterator
from concurrent.futures import Executor, Future, ProcessPoolExecutor
from contextlib import contextmanager, suppress
from multiprocessing.connection import Connection
from typing import Any

DRAWING_PROCESSES = 2
"""Figures drawn at once: the cases of a file end together, so their figures (two a case) are drawn side by side
once the pool's workers are idle."""


class DrawingError(RuntimeError):
    """The drawing process ended before a figure was drawn, or a figure's result could not be passed back."""


class ForkingDrawer(Executor):
    """Runs each call submitted on a pool of ``processes`` forks of one drawing process, which imported ``imports``
    as it started (while the caller goes on). ``shutdown`` waits for the calls queued. The drawing process and its
    pool ignore the stop signals: the command ends them."""

    def __init__(self, imports: Collection[str], processes: int = DRAWING_PROCESSES) -> None:
        context = multiprocessing.get_context("fork")
        self._jobs, jobs_end = context.Pipe()
        self._results, results_end = context.Pipe(duplex=False)
        self._process = context.Process(target=_serve, args=(tuple(imports), processes, jobs_end, results_end),
                                        name="bodebench-drawing")
        self._process.start()
        jobs_end.close()
        results_end.close()
        self._lock = threading.Lock()
        self._pending: dict[int, Future[Any]] = {}
        self._count = 0
        self._closed = False
        self._reader = threading.Thread(target=self._read, name="bodebench-drawing-results", daemon=True)
        self._reader.start()

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future[Any]:
        future: Future[Any] = Future()
        try:
            call = pickle.dumps((fn, args, kwargs))
        except Exception as exc:  # as a process pool does: the future holds why
            future.set_exception(exc)
            return future
        with self._lock:
            if self._closed:
                raise RuntimeError("cannot draw after the drawing process was shut down")
            job = self._count
            self._count += 1
            self._pending[job] = future
            try:
                self._jobs.send((job, call))
            except (OSError, ValueError) as exc:  # the drawing process has gone
                del self._pending[job]
                future.set_exception(DrawingError(f"the drawing process has ended: {exc}"))
        return future

    def _read(self) -> None:
        """Each result, as it comes, to its future; the futures left when the drawing process ends fail."""
        while True:
            try:
                job, ok, value = self._results.recv()
            except (EOFError, OSError):
                break
            with self._lock:
                future = self._pending.pop(job)
            if ok:
                future.set_result(value)
            else:
                future.set_exception(value)
        with self._lock:
            left = list(self._pending.values())
            self._pending.clear()
        for future in left:
            future.set_exception(DrawingError("the drawing process ended before drawing the figure"))

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        """No more calls; the queued ones are drawn (``cancel_futures`` is not honoured: a figure asked for is
        drawn). ``wait``: return once they are."""
        with self._lock:
            if not self._closed:
                self._closed = True
                with suppress(OSError, ValueError):
                    self._jobs.send(None)
        if wait:
            self._process.join()
            self._reader.join()
            self._jobs.close()
            self._results.close()


def _serve(imports: tuple[str, ...], processes: int, jobs: Connection, results: Connection) -> None:
    """The drawing process: import ``imports``, start a pool of ``processes`` forks of itself, hand it each job
    received and send back each job's (job, ok, result or exception); end once told (None) or the caller has gone,
    and every job received is done."""
    _import_all(imports)
    sending = threading.Lock()

    def send_back(job: int, future: Future[Any]) -> None:
        error = future.exception()
        with sending:
            try:
                results.send((job, error is None, future.result() if error is None else error))
            except Exception as exc:  # an unpicklable result, or the caller has gone
                with suppress(OSError, ValueError):
                    results.send((job, False, DrawingError(f"the figure's result could not be passed back: {exc}")))

    with ProcessPoolExecutor(max_workers=processes, mp_context=multiprocessing.get_context("fork")) as pool:
        for _ in range(processes):
            pool.submit(int)  # fork them now, before the first figure
        while True:
            try:
                message = jobs.recv()
            except EOFError:
                message = None
            if message is None:
                break
            job, call = message
            try:
                fn, args, kwargs = pickle.loads(call)
                future = pool.submit(fn, *args, **kwargs)
            except Exception as exc:  # not to be had here, or a pool broken by a process that died
                future = Future()
                future.set_exception(exc)
            future.add_done_callback(functools.partial(send_back, job))


def _import_all(imports: tuple[str, ...]) -> None:
    """A pool process's start where processes cannot be forked: ignore the stop signals, import ``imports``."""
    from bodebench.drivers.stop_signals import STOP_SIGNALS

    for signum in STOP_SIGNALS:
        signal.signal(signum, signal.SIG_IGN)
    for name in imports:
        importlib.import_module(name)


@contextmanager
def drawing_executor(imports: Collection[str]) -> Iterator[Executor]:
    """Where an offline sweep's plots are drawn, started now so that ``imports`` (the plotting modules) load while
    this process loads the compiled kernels and the sweep's pool starts (the pool's workers never load them): a
    :class:`ForkingDrawer`, else a pool of :data:`DRAWING_PROCESSES` processes. Shut down (the plots queued drawn)
    when the block ends."""
    executor: Executor
    if "fork" in multiprocessing.get_all_start_methods():
        executor = ForkingDrawer(imports)
    else:
        executor = ProcessPoolExecutor(max_workers=DRAWING_PROCESSES, initializer=_import_all,
                                       initargs=(tuple(imports),))
        for _ in range(DRAWING_PROCESSES):
            executor.submit(int)  # start the processes now
    try:
        yield executor
    finally:
        executor.shutdown(wait=True)
