"""The offline experiment on its executors: every case in one pool, plots drawn there too, a Dask cluster, the
compiled kernels compiled once per machine rather than once per worker."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import textwrap
import threading
import tomllib
from concurrent.futures import Future, ProcessPoolExecutor, ThreadPoolExecutor
from functools import partial
from pathlib import Path

import numpy as np
import pytest
from helpers import interrupt_after

from bodebench.apps.cli import main
from bodebench.apps.plots import write_plots
from bodebench.bench.events import CaseBegins, CaseSaved, PointFinished
from bodebench.bench.offline import in_flight_limit, measure_cases
from bodebench.bench.procedure import SweepProcedure
from bodebench.io.config import parse_config
from bodebench.io.results import load_response
from bodebench.sim.plants import FirstOrderLag, LinearOscillator

ROOT = Path(__file__).resolve().parent.parent

CASES = """
title = "three plants"
[plant]
model = "linear"
[excitation]
amplitude = 0.5
frequencies_hz = [1.0, 4.0, 5.0, 9.0]
[analysis]
harmonics = [1, 2]
tolerance_percent = 0.05
[cases.light.plant]
mass = 1e-3
stiffness = 1.0
damping_ratio = 0.05
[cases.heavy.plant]
mass = 1e-3
stiffness = 1.0
damping_ratio = 0.7
[cases.lag.plant]
model = "lag"
time_constant = 0.05
gain = 2.0
"""


def exact(case_name: str, f: np.ndarray) -> np.ndarray:
    """The plants' exact first-harmonic response at ``f`` (Hz)."""
    plant = (FirstOrderLag(0.05, 2.0) if case_name == "lag"
             else LinearOscillator(1e-3, 1.0, 0.05 if case_name == "light" else 0.7))
    return plant.frequency_response(f)[:, 0]


def sorted_points(response: object) -> list[tuple[float, int, float, float, int, str]]:
    return sorted((p.frequency_hz, p.harmonic, p.gain, p.phase_deg, p.periods, p.status)
                  for p in response.points)  # type: ignore[attr-defined]


def test_one_pool_for_every_case_gives_the_in_order_results_and_events_case_by_case(tmp_path: Path) -> None:
    config = parse_config(tomllib.loads(CASES), "cases.toml")
    inline = SweepProcedure(config, tmp_path / "inline").run()
    events: list[object] = []
    with ProcessPoolExecutor(2) as pool:
        pooled = SweepProcedure(config, tmp_path / "pool", listener=events.append, executor=pool,
                                plots=partial(write_plots, formats=("png",))).run()
    assert [o.case.name for o in pooled] == ["light", "heavy", "lag"]
    for a, b in zip(inline, pooled, strict=True):
        assert sorted_points(a.response) == sorted_points(b.response)  # bit-identical however they ran
        on_disk = load_response(b.directory)
        assert sorted_points(on_disk) == sorted_points(b.response)
        first = b.response.select(harmonic=1)
        assert np.allclose(first.gain, np.abs(exact(b.case.name, first.frequency_hz)), rtol=1e-3)
        assert [f.name for f in b.files] == ["bode.png", "periods.png"]
        assert all(f.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for f in b.files)
    # events: each case begins, then its four frequencies, in case order; saved once its plots are on disk
    begins = [i for i, e in enumerate(events) if isinstance(e, CaseBegins)]
    assert [events[i].index for i in begins] == [0, 1, 2]  # type: ignore[attr-defined]
    for k, start in enumerate(begins):
        end = begins[k + 1] if k + 1 < len(begins) else len(events)
        finished = [e for e in events[start:end] if isinstance(e, PointFinished)]
        assert sorted(e.points[0].frequency_hz for e in finished) == [1.0, 4.0, 5.0, 9.0]
    saved = [e for e in events if isinstance(e, CaseSaved)]
    assert [e.index for e in saved] == [0, 1, 2] and all(len(e.files) == 2 for e in saved)


def test_a_resumed_pool_run_measures_only_what_is_missing(tmp_path: Path) -> None:
    config = parse_config(tomllib.loads(CASES), "cases.toml")
    with ProcessPoolExecutor(2) as pool:
        full = SweepProcedure(config, tmp_path / "full", executor=pool).run()
        # cut the second case's file after its first frequency's rows, as an interruption would
        interrupt_after(tmp_path / "full" / "heavy", 2)
        events: list[object] = []
        resumed = SweepProcedure(config, tmp_path / "full", listener=events.append, executor=pool,
                                 existing="resume").run()
    measured = [e for e in events if isinstance(e, PointFinished)]
    assert len(measured) == 3  # the heavy case's three missing frequencies, nothing else
    for a, b in zip(full, resumed, strict=True):
        assert sorted_points(a.response) == sorted_points(b.response)
        assert sorted_points(load_response(b.directory)) == sorted_points(a.response)


@pytest.mark.slow
def test_simulate_plot_formats_and_bad_arguments(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = tmp_path / "cases.toml"
    cfg.write_text(CASES)
    assert main(["simulate", str(cfg), "--out", str(tmp_path / "none"), "--jobs", "1", "--plots", "none",
                 "--quiet"]) == 0
    assert sorted(p.name for p in (tmp_path / "none" / "lag").iterdir()) == ["response.csv",
                                                                             "response.csv-metadata.json",
                                                                             "response.json"]
    assert main(["simulate", str(cfg), "--out", str(tmp_path / "vec"), "--jobs", "1", "--plots", "svg,pdf",
                 "--quiet"]) == 0
    names = sorted(p.name for p in (tmp_path / "vec" / "light").iterdir())
    assert names == ["bode.pdf", "bode.svg", "periods.pdf", "periods.svg", "response.csv", "response.csv-metadata.json",
                     "response.json"]
    assert (tmp_path / "vec" / "light" / "bode.pdf").read_bytes()[:5] == b"%PDF-"
    capsys.readouterr()
    with pytest.raises(SystemExit) as exc:
        main(["simulate", str(cfg), "--out", str(tmp_path / "x"), "--jobs", "-1"])
    assert exc.value.code == 2
    assert "argument --jobs: must be >= 1 (worker processes), got -1" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()
    with pytest.raises(SystemExit) as exc:
        main(["simulate", str(cfg), "--out", str(tmp_path / "y"), "--plots", "png,jpg"])
    assert exc.value.code == 2
    assert "plot format jpg unknown; choose from png, svg, pdf" in capsys.readouterr().err


@pytest.mark.parametrize("jobs", ["1", "2"])
def test_plots_the_disk_will_not_take_are_one_line_and_the_points_are_kept(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], jobs: str) -> None:
    """A case's Bode plot cannot be written (its path is a directory), drawn here or by the drawing process: one
    line naming the file and the points kept, exit status 1, every point on disk with its record."""
    cfg = tmp_path / "cases.toml"
    cfg.write_text(CASES)
    out = tmp_path / "out"
    (out / "heavy" / "bode.png").mkdir(parents=True)
    assert main(["simulate", str(cfg), "--out", str(out), "--jobs", jobs, "--quiet"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    heavy = out / "heavy"
    assert err == [f"bodebench: stopped: output: {heavy}: cannot write the plots: {heavy / 'bode.png'}: "
                   f"Is a directory; {3 * 4 * 2} points kept in {out}"], err
    assert "Traceback" not in "\n".join(err)
    for case in ("light", "heavy", "lag"):
        assert len(load_response(out / case).points) == 4 * 2
        assert json.loads((out / case / "response.json").read_text())["runs"]


MANY = """
title = "many"
[plant]
model = "lag"
time_constant = 0.05
gain = 2.0
[excitation]
amplitude = 0.5
frequencies_hz = [0.5, 0.7, 1.0, 1.4, 2.0, 2.8, 4.0, 5.6, 8.0, 11.0, 16.0, 22.0, 32.0, 45.0, 64.0, 90.0]
[analysis]
harmonics = [1, 2, 3]
tolerance_percent = 0.1
"""


def _simulate_limited(cfg: Path, out: Path, file_bytes: int) -> subprocess.CompletedProcess[str]:
    """``bodebench simulate`` whose files may not grow past ``file_bytes`` (a full disk, as the process sees it)."""
    import resource

    def limited() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (file_bytes, file_bytes))

    return subprocess.run([sys.executable, "-m", "bodebench", "simulate", str(cfg), "--out", str(out), "--quiet",
                           "--plots", "none"], capture_output=True, text=True, timeout=300, preexec_fn=limited)


@pytest.mark.skipif(os.name != "posix", reason="a file size limit")
def test_a_disk_that_fills_during_a_simulate_is_one_line_and_every_point_written_is_kept(tmp_path: Path) -> None:
    """Files limited to half of what the sweep writes: the sweep stops at the first point the disk will not take,
    in one line naming the frequency and the points kept, all of them on disk; limited below what a results
    directory needs to start, one line and exit status 2 before any point."""
    cfg = tmp_path / "many.toml"
    cfg.write_text(MANY)
    assert main(["simulate", str(cfg), "--out", str(tmp_path / "full"), "--quiet", "--plots", "none"]) == 0
    largest = max(path.stat().st_size for path in (tmp_path / "full").iterdir())
    out = tmp_path / "half"
    proc = _simulate_limited(cfg, out, largest // 2)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 1 and len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    kept = load_response(out, drop_torn_row=True).points
    assert 0 < len(kept) < 16 * 3
    assert re.fullmatch(rf"bodebench: stopped: output: {re.escape(str(out))}: cannot write the point at [0-9.]+ Hz: "
                        rf"File too large.*; {len(kept)} points kept in {re.escape(str(out))}", lines[0]), lines[0]
    proc = _simulate_limited(cfg, tmp_path / "none", 1024)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip().splitlines() == [f"bodebench: {tmp_path / 'none'}: cannot write results there: "
                                                "File too large"], proc.stderr
    (tmp_path / "a-file").write_text("")
    assert main(["simulate", str(cfg), "--out", str(tmp_path / "a-file"), "--quiet"]) == 2


@pytest.mark.slow
def test_simulate_on_a_local_dask_cluster_gives_the_pool_results(tmp_path: Path) -> None:
    cfg = tmp_path / "cases.toml"
    cfg.write_text(CASES)
    assert main(["simulate", str(cfg), "--out", str(tmp_path / "inline"), "--jobs", "1", "--quiet"]) == 0
    proc = subprocess.run([sys.executable, "-m", "bodebench", "simulate", str(cfg), "--out", str(tmp_path / "dask"),
                           "--executor", "local", "--jobs", "2", "--quiet"], capture_output=True, text=True,
                          timeout=600, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    for case in ("light", "heavy", "lag"):
        assert sorted_points(load_response(tmp_path / "dask" / case)) == \
            sorted_points(load_response(tmp_path / "inline" / case))
        assert (tmp_path / "dask" / case / "bode.png").exists()  # drawn on the cluster


@pytest.mark.slow
@pytest.mark.parametrize("address", ["tcp://127.0.0.1:9", "127.0.0.1", "tcp://127.0.0.1:port"])
def test_a_missing_dask_scheduler_is_one_line(tmp_path: Path, address: str) -> None:
    """Nothing listening (a refused connection, said at once rather than after the client's timeout), or not an
    address at all: one line naming it, nothing written."""
    cfg = tmp_path / "cases.toml"
    cfg.write_text(CASES)
    proc = subprocess.run([sys.executable, "-m", "bodebench", "simulate", str(cfg), "--out", str(tmp_path / "d"),
                           "--executor", address, "--quiet"], capture_output=True, text=True,
                          timeout=300, cwd=tmp_path)
    assert proc.returncode == 2
    assert proc.stderr.startswith(f"bodebench: no Dask scheduler at {address}: ")
    assert len(proc.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "d").exists()


class CountingPool(ThreadPoolExecutor):
    """A thread pool that keeps the most tasks it ever held submitted and not yet done."""

    def __init__(self, workers: int) -> None:
        super().__init__(workers)
        self.outstanding = self.most = 0
        self._count = threading.Lock()

    def submit(self, fn, /, *args, **kwargs):  # type: ignore[no-untyped-def]
        with self._count:
            self.outstanding += 1
            self.most = max(self.most, self.outstanding)
        future: Future[object] = super().submit(fn, *args, **kwargs)
        future.add_done_callback(self._done)
        return future

    def _done(self, _: Future[object]) -> None:
        with self._count:
            self.outstanding -= 1


def test_a_limited_number_of_frequencies_in_flight_gives_every_point_once_and_the_same_points(
        tmp_path: Path) -> None:
    config = parse_config(tomllib.loads(CASES), "cases.toml")
    everything = sorted((k, p.frequency_hz, p.harmonic, p.gain, p.phase_deg, p.periods)
                        for k, points in measure_cases(config.cases) for p in points)
    for limit in (1, 3, None):
        with CountingPool(2) as pool:
            found = sorted((k, p.frequency_hz, p.harmonic, p.gain, p.phase_deg, p.periods)
                           for k, points in measure_cases(config.cases, pool, in_flight=limit) for p in points)
        assert found == everything  # twelve frequencies, each once, bit for bit
        assert pool.most <= (12 if limit is None else limit)  # never more submitted and not done
    with ProcessPoolExecutor(3) as pool:
        assert in_flight_limit(pool) == 6
    assert in_flight_limit(None) is None


COMPILE_ONCE = textwrap.dedent("""
    import json, multiprocessing, os, sys, time
    from bodebench.bench.offline import default_executor

    def stats(_=None):
        import numba
        from bodebench.sim import _kernels
        time.sleep(0.5)  # long enough that every worker of the pool takes one of these
        misses = hits = 0
        for name in dir(_kernels):
            d = getattr(_kernels, name)
            if isinstance(d, numba.core.registry.CPUDispatcher):
                misses += sum(d.stats.cache_misses.values())
                hits += sum(d.stats.cache_hits.values())
        return os.getpid(), misses, hits

    if __name__ == "__main__":
        multiprocessing.set_start_method(sys.argv[1])
        with default_executor(2, models=("lag",)) as pool:
            here = stats()[1:]
            found = {}
            for _ in range(10):
                for pid, misses, hits in pool.map(stats, range(2)):
                    found[pid] = (misses, hits)
                if len(found) == 2:
                    break
        print(json.dumps({"here": here, "workers": sorted(found.values())}))
""")


@pytest.mark.slow
@pytest.mark.parametrize("start", ["fork", "spawn"])
def test_the_pool_compiles_the_kernels_once_into_an_empty_cache(tmp_path: Path, start: str) -> None:
    script = tmp_path / "compile_once.py"
    script.write_text(COMPILE_ONCE)
    cache = tmp_path / "cache"
    cache.mkdir()
    proc = subprocess.run([sys.executable, str(script), start], capture_output=True, text=True, timeout=900,
                          env=dict(os.environ, NUMBA_CACHE_DIR=str(cache)))
    assert proc.returncode == 0, proc.stderr
    found = json.loads(proc.stdout)
    workers = found["workers"]
    assert len(workers) == 2
    if start == "fork":  # compiled here, before the pool forked: the workers have this process' kernels
        here_misses, here_hits = found["here"]
        assert here_misses > 0 and here_hits == 0
        assert workers == [found["here"], found["here"]]
    else:  # this process loads nothing; one worker compiled the lag's kernels, the other loaded every one of them
        assert found["here"] == [0, 0]
        (loaded_misses, loaded_hits), (compiled_misses, _) = workers
        assert compiled_misses > 0
        assert loaded_misses == 0 and loaded_hits == compiled_misses
    assert list(cache.rglob("*.nbi"))


@pytest.mark.slow
def test_the_first_run_says_it_compiles_and_later_runs_do_not(tmp_path: Path) -> None:
    """``bodebench simulate`` into an empty numba cache says, before its first point, that it compiles the plant's
    step loops and about how long that takes; the same run again, the cache now filled by the first, says nothing
    of it (and a quiet run never does)."""
    cache = tmp_path / "cache"
    cache.mkdir()
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
    root = Path(__file__).resolve().parents[1]

    def simulate(out: str, *extra: str) -> list[str]:
        proc = subprocess.run([sys.executable, "-m", "bodebench", "simulate", str(root / "configs" / "sim_can.toml"),
                               "--set", "excitation.frequencies_hz=[5]", "--plots", "none", "--out",
                               str(tmp_path / out), *extra], capture_output=True, text=True, timeout=900, env=env)
        assert proc.returncode == 0, proc.stderr
        return proc.stderr.splitlines()

    quiet = simulate("quiet", "-q")
    assert not any("compiling" in line for line in quiet), quiet
    assert list(cache.rglob("*.nbi"))  # the quiet run compiled, silently
    for path in cache.rglob("*.nb*"):
        path.unlink()
    first = simulate("first")
    assert first[0].startswith("bodebench: compiling the step loops of the simulated plant (coulomb): about 3 s"), first
    again = simulate("again")
    assert not any("compiling" in line for line in again), again


SLOW_AND_FAST = """
title = "one fast point, one that never settles"
[plant]
model = "coulomb"
mass = 2.533e-4
stiffness = 1.0
friction = 0.006
[excitation]
amplitude = 0.01
frequencies_hz = [2.0, 10.0]
[analysis]
harmonics = [1]
tolerance_percent = 0.01
max_periods = 200000
"""


@pytest.mark.slow
def test_ctrl_c_of_simulate_is_one_line_and_keeps_the_points_measured(tmp_path: Path) -> None:
    """Ctrl-C (SIGINT to the foreground group) while one worker measures a point that never settles (Fbar 0.6 at its
    natural frequency) and the other, its point done, waits: the workers and the drawing process end without a
    word, the command says what it kept, and the point measured is on disk."""
    import signal

    cfg = tmp_path / "slow.toml"
    cfg.write_text(SLOW_AND_FAST)
    out = tmp_path / "out"
    run = subprocess.Popen([sys.executable, "-m", "bodebench", "simulate", str(cfg), "--out", str(out), "--jobs", "2"],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                           cwd=tmp_path)
    try:
        assert run.stderr is not None
        first = run.stderr.readline()  # the fast point's progress line
        assert "2 Hz" in first, first
        os.killpg(run.pid, signal.SIGINT)
        _, err = run.communicate(timeout=120)
    finally:
        if run.poll() is None:
            os.killpg(run.pid, signal.SIGKILL)
    assert run.returncode == 128 + signal.SIGINT, err
    assert "Traceback" not in err, err
    assert err.strip().splitlines()[-1] == "bodebench: interrupted (SIGINT); points already measured are on disk"
    assert [p.frequency_hz for p in load_response(out).points] == [2.0]
