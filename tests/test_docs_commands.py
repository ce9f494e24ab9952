"""Every command the user documentation shows in a shell block, and every Python block, runs as written, in a copy of
the repository's configs, against the simulated drives: exit status 0 and no traceback.

A ``sh`` block is a script: each line is a command (``$ `` prompts marked; lines without one in a block that has
them are the output shown). A command that serves a drive until stopped (``sim-controller`` without ``--seconds``)
is started in the background and stopped once the block's other commands have run; a ``/dev/pts/N`` the docs show
is replaced by the port that drive opened. ``pip install`` lines are what CI itself did before the tests.
Hardware set-up (``ip link``, driver installers) is shown in ``text`` blocks, which are not run.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
BLOCK = re.compile(r"^```sh\n(.*?)^```", re.S | re.M)
DOCUMENTS = tuple(["README.md"] + [str(p.relative_to(ROOT)) for p in sorted((ROOT / "docs").rglob("*.md"))
                                   if p.name != "index.md" and BLOCK.search(p.read_text(encoding="utf-8"))])
"""The user documentation whose shell blocks are run (the site's home page shows README's own block)."""
PTS = re.compile(r"/dev/pts/\d+")


def shell_blocks(document: str) -> list[list[str]]:
    """The commands of each ``sh`` block of ``document``, comments stripped, output lines left out."""
    blocks = []
    for body in BLOCK.findall((ROOT / document).read_text(encoding="utf-8")):
        lines = [line for line in body.splitlines() if line.strip()]
        prompted = any(line.startswith("$ ") for line in lines)
        commands = [line[2:] if prompted else line for line in lines if not prompted or line.startswith("$ ")]
        blocks.append([_without_comment(c).strip() for c in commands if _without_comment(c).strip()])
    return blocks


COMMENT = re.compile(r"\s+#\s")


def _without_comment(line: str) -> str:
    """``line`` up to its comment (`` # ...`` after the command)."""
    return COMMENT.split(line, maxsplit=1)[0]


def _run(command: str, cwd: Path, env: dict[str, str], timeout: float) -> subprocess.CompletedProcess[str]:
    words = shlex.split(command)
    if words[0] == "bodebench":
        words = [sys.executable, "-m", "bodebench", *words[1:]]
    elif words[0] == "python":
        words[0] = sys.executable
    return subprocess.run(words, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)


def _serve(command: str, cwd: Path, env: dict[str, str]) -> tuple[subprocess.Popen[str], str]:
    """A standalone simulated drive started in the background; (its process, the port it says it opened)."""
    words = [sys.executable, "-m", "bodebench", *shlex.split(command)[1:]]
    drive = subprocess.Popen(words, cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                             start_new_session=True)
    assert drive.stdout is not None
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        line = drive.stdout.readline()
        if not line:
            break
        found = PTS.search(line)
        if found:
            return drive, found.group(0)
    drive.kill()
    raise AssertionError(f"{command}: no port announced")


def _stop(drive: subprocess.Popen[str]) -> None:
    os.killpg(drive.pid, signal.SIGINT)
    try:
        drive.wait(30)
    except subprocess.TimeoutExpired:
        os.killpg(drive.pid, signal.SIGKILL)
        drive.wait(10)


def _workspace(tmp_path: Path) -> Path:
    """A directory holding a copy of the repository's configs (the docs run their commands from the root)."""
    shutil.copytree(ROOT / "configs", tmp_path / "configs")
    return tmp_path


PRODUCES = ("--out", "--write-config", "--log-bus")
"""Options whose value is a file or directory a command writes, for a later command to read."""


def _is_served(command: str) -> bool:
    """A standalone simulated drive that runs until stopped."""
    return command.startswith("bodebench sim-controller") and "--seconds" not in command


def _writes(words: list[str]) -> list[str]:
    """The paths a command writes (the values of its ``PRODUCES`` options)."""
    return [value for option, value in zip(words, words[1:], strict=False) if option in PRODUCES]


def _is_file_here(path: str) -> bool:
    """A file written in the working directory (a config, a DBC), which another such file may name."""
    return bool(Path(path).suffix) and not Path(path).parent.name


def chains(document: str) -> list[list[str]]:
    """The commands of ``document`` (``pip install`` and pytest lines left out: CI ran them to get here) grouped into
    chains that need nothing from each other, each run in a workspace of its own: a command joins the chain of a
    command of its block that wrote a path it names (``--out``, ``--write-config``, ``--log-bus``); the commands of
    a block that write files (a config, a DBC: a name with a suffix, which another such file may name) share one
    chain; a command on a ``/dev/pts/N`` port joins the chain of its block's served drive; a command shown again is
    run once."""
    found: list[list[str]] = []
    seen: set[str] = set()
    for block in shell_blocks(document):
        owner: dict[str, int] = {}  # a path written in this block -> its chain
        files = -1  # the chain of this block's commands that write files
        served = -1
        for command in (part.strip() for line in block for part in line.split("&&")):
            if command.startswith("pip install") or "pytest" in command or command in seen:
                continue
            seen.add(command)
            words = shlex.split(command)
            needs = [owner[w] for w in words if w in owner]
            if PTS.search(command) and served >= 0:
                needs.append(served)
            if files >= 0 and any(map(_is_file_here, _writes(words))):
                needs.append(files)
            chain = needs[0] if needs else len(found)
            if chain == len(found):
                found.append([])
            found[chain].append(command)
            for value in _writes(words):
                owner[value] = chain
                if _is_file_here(value) and files < 0:
                    files = chain
            if _is_served(command):
                served = chain
    return found


CHAINS = [(document, i) for document in DOCUMENTS for i in range(len(chains(document)))]
"""Each chain of commands of the documents, a test of its own (so they spread over the test workers)."""


@pytest.mark.slow
@pytest.mark.parametrize("document, chain", CHAINS, ids=[f"{d}-{i}" for d, i in CHAINS])
def test_every_shell_command_of_the_docs_runs_as_written(tmp_path: Path, document: str, chain: int) -> None:
    cwd = _workspace(tmp_path)
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    drive: subprocess.Popen[str] | None = None
    port = ""
    try:
        for command in chains(document)[chain]:
            if _is_served(command):
                drive, port = _serve(command, cwd, env)  # it announced its port: it runs
                continue
            if port:
                command = PTS.sub(port, command)
            done = _run(command, cwd, env, timeout=900)
            assert done.returncode == 0, f"{document}: {command}\n{done.stdout[-2000:]}\n{done.stderr[-2000:]}"
            assert "Traceback" not in done.stderr, f"{document}: {command}\n{done.stderr[-2000:]}"
    finally:
        if drive is not None:
            _stop(drive)


def test_commands_that_read_what_another_wrote_run_in_its_chain() -> None:
    """The chains of docs/getting-started.md: the re-analysis with the sweep that wrote its directory, the sweep of
    a written config and the sweep on the served drive's port with that drive; every other command on its own."""
    found = chains("docs/getting-started.md")
    assert ["bodebench run configs/sim_can.toml --out results/sim_can_log --log-bus results/sim_can.asc",
            "bodebench analyse results/sim_can_log --criterion full"] in found
    rehearsal = next(c for c in found if c[0].endswith("--write-config bench.toml"))
    assert rehearsal[1:] == ["bodebench run bench.toml --out results/rehearsal",
                             "bodebench run configs/sim_serial.toml --port /dev/pts/3 --out results/rehearsal2"]
    assert ["bodebench example real_can --out my_can_drive.toml", "bodebench example real_can.dbc --out real_can.dbc",
            "bodebench check my_can_drive.toml", "bodebench dbc configs/sim_can.toml --out sim_can.dbc"] in found
    commands = [c for block in shell_blocks("docs/getting-started.md") for c in block
                if not c.startswith("pip install")]
    assert sorted(c for chain in found for c in chain) == sorted(set(commands))
    assert len(found) >= 10


PYTHON_BLOCK = re.compile(r"^```python\n(.*?)^```", re.S | re.M)
PYTHON_DOCUMENTS = tuple(str(p.relative_to(ROOT)) for p in sorted((ROOT / "docs").rglob("*.md"))
                         if PYTHON_BLOCK.search(p.read_text(encoding="utf-8")))
"""The pages that show Python code: each block runs as a script."""


@pytest.mark.slow
@pytest.mark.parametrize("document", PYTHON_DOCUMENTS)
def test_every_python_block_of_the_docs_runs_as_written(tmp_path: Path, document: str) -> None:
    cwd = _workspace(tmp_path)
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    for i, block in enumerate(PYTHON_BLOCK.findall((ROOT / document).read_text(encoding="utf-8"))):
        script = cwd / f"block_{i}.py"
        script.write_text(block, encoding="utf-8")
        done = subprocess.run([sys.executable, str(script)], cwd=cwd, env=env, capture_output=True, text=True,
                              timeout=900)
        assert done.returncode == 0, f"{document} block {i}:\n{block}\n{done.stderr[-3000:]}"


def test_the_site_home_page_shows_the_readme_commands() -> None:
    """docs/index.md starts with the README's two commands, so running README's block covers it."""
    assert shell_blocks("docs/index.md")[0] == shell_blocks("README.md")[0]


def test_the_documents_run_are_the_ones_with_commands() -> None:
    assert {"README.md", "docs/first-real-sweep.md", "docs/getting-started.md", "docs/canopen.md"} <= set(DOCUMENTS)
    assert "docs/python-api.md" in PYTHON_DOCUMENTS


def test_the_tests_index_lists_every_test_file_once() -> None:
    """tests/README.md groups the test files by the part of the package they check: each file once, none that is
    not there."""
    index = (ROOT / "tests" / "README.md").read_text()
    listed = re.findall(r"^\| `(test_\w+\.py)` \|", index, flags=re.MULTILINE)
    present = sorted(p.name for p in (ROOT / "tests").glob("test_*.py"))
    assert sorted(listed) == present, (sorted(set(present) - set(listed)), sorted(set(listed) - set(present)))
    assert len(listed) == len(set(listed))
