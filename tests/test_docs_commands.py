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


@pytest.mark.slow
@pytest.mark.parametrize("document", DOCUMENTS)
def test_every_shell_command_of_the_docs_runs_as_written(tmp_path: Path, document: str) -> None:
    cwd = _workspace(tmp_path)
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    ran = 0
    done_before: set[str] = set()
    for block in shell_blocks(document):
        drive: subprocess.Popen[str] | None = None
        port = ""
        try:
            for command in (part.strip() for line in block for part in line.split("&&")):
                if command.startswith("pip install") or "pytest" in command or command in done_before:
                    continue  # what CI ran to get here, or a command shown again in another section
                if command.startswith("bodebench sim-controller") and "--seconds" not in command:
                    drive, port = _serve(command, cwd, env)
                    continue
                if port:
                    command = PTS.sub(port, command)
                done = _run(command, cwd, env, timeout=900)
                assert done.returncode == 0, f"{document}: {command}\n{done.stdout[-2000:]}\n{done.stderr[-2000:]}"
                assert "Traceback" not in done.stderr, f"{document}: {command}\n{done.stderr[-2000:]}"
                done_before.add(command)
                ran += 1
        finally:
            if drive is not None:
                _stop(drive)
    assert ran >= 1


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
