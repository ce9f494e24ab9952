"""Without numba the simulated plants run as plain Python: the same sweep, to round-off, and a warning that says
what it costs. The interpreter that measures has numba made unimportable by its ``sitecustomize``."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from bodebench.bench.procedure import SweepProcedure
from bodebench.io.config import parse_config
from bodebench.io.results import load_response

CONFIG = {
    "plant": {"model": "coulomb", "mass": 2.533e-4, "stiffness": 1.0, "friction": 0.008},
    "excitation": {"amplitude": 0.01, "frequencies_hz": [3.0, 20.0]},
    "analysis": {"tolerance_percent": 0.1, "steps_per_period": 100},
}


def test_an_offline_sweep_without_numba_agrees_with_the_compiled_one(tmp_path: Path) -> None:
    SweepProcedure(parse_config(CONFIG, "x.toml"), tmp_path / "compiled").run()
    site = tmp_path / "site"
    site.mkdir()
    (site / "sitecustomize.py").write_text("import sys\nsys.modules['numba'] = None\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(site), os.environ.get("PYTHONPATH")]))}
    config = tmp_path / "x.toml"  # CONFIG as TOML
    lines = ['[plant]\nmodel = "coulomb"\nmass = 2.533e-4\nstiffness = 1.0\nfriction = 0.008\n',
             '[excitation]\namplitude = 0.01\nfrequencies_hz = [3.0, 20.0]\n',
             '[analysis]\ntolerance_percent = 0.1\nsteps_per_period = 100\n']
    config.write_text("".join(lines))
    done = subprocess.run([sys.executable, "-c", "import sys; from bodebench.sim._jit import HAVE_NUMBA; "
                           "print(HAVE_NUMBA); from bodebench.apps.cli import main; "
                           f"sys.exit(main(['simulate', {str(config)!r}, '--out', {str(tmp_path / 'plain')!r}, "
                           "'--jobs', '1', '--plots', 'none']))"],
                          env=env, capture_output=True, text=True, timeout=1200)
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines()[0] == "False"
    assert "numba is not installed: the simulated plants run as plain Python" in done.stderr
    compiled, plain = load_response(tmp_path / "compiled"), load_response(tmp_path / "plain")
    assert [(p.frequency_hz, p.harmonic, p.status) for p in plain] == [
        (p.frequency_hz, p.harmonic, p.status) for p in compiled]
    a, b = plain.complex_response(), compiled.complex_response()
    assert np.all(np.abs(a - b) <= 1e-9 * np.abs(b))
