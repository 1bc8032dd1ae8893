"""The acceptance suite: every command the README and docs/ show, run through its console script as a user runs
it, with the default configuration, on the bundled short recordings (docs/acceptance.md).

Tests whose default run is longer than CI's budget run only with DIFFSTIR_ACCEPTANCE=full
(scripts/acceptance.sh)."""

from __future__ import annotations

import json
import os
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

import diffstir
from diffstir.recording import load_recording

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = Path(diffstir.__file__).resolve().parent / "data" / "examples"
FULL = os.environ.get("DIFFSTIR_ACCEPTANCE") == "full"

#: a default run that does not fit in CI's budget: scripts/acceptance.sh runs it
full_only = pytest.mark.skipif(not FULL, reason="a default run longer than CI's budget; scripts/acceptance.sh "
                                                "runs it (docs/acceptance.md)")


#: the thread counts of torch (OpenMP) and the BLAS libraries. Under pytest-xdist each test process has one core,
#: and a command's two spinning OpenMP threads beside the other process run several times slower than one
#: (tests/conftest.py); the command's own worker processes follow its thread count (diffstir.parallel).
THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")

#: where ``run`` appends one line per command (scripts/acceptance.sh sets it; unset: no log)
TIMING_LOG = os.environ.get("DIFFSTIR_ACCEPTANCE_LOG")


def run(*command: str, cwd: Path, timeout: float) -> subprocess.CompletedProcess:
    """``command`` (a console script and its arguments) in ``cwd``, its output captured, within ``timeout`` [s].
    With ``TIMING_LOG`` set, one tab-separated line is appended there: the UTC start, the wall time [s], the exit
    status, the command and its output's last line (a fit's or an experiment's summary)."""
    env = {k: v for k, v in os.environ.items() if k != "HYDRA_FULL_ERROR"}
    if os.environ.get("PYTEST_XDIST_WORKER"):  # the suite's other process holds another core: one thread each
        env.update({name: "1" for name in THREAD_VARIABLES})
    started, clock = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), time.perf_counter()
    try:
        result = subprocess.run(list(command), cwd=cwd, capture_output=True, text=True, timeout=timeout, env=env)
    except subprocess.TimeoutExpired:
        _log(started, clock, "timeout", command, f"past the test's {timeout:g} s")
        raise
    last = (result.stdout.strip().splitlines() or result.stderr.strip().splitlines() or [""])[-1]
    _log(started, clock, str(result.returncode), command, last)
    return result


def _log(started: str, clock: float, status: str, command: tuple[str, ...], last: str) -> None:
    if TIMING_LOG:
        with open(TIMING_LOG, "a", encoding="utf-8") as log:
            log.write(f"{started}\t{time.perf_counter() - clock:.1f}\t{status}\t{' '.join(command)}\t{last}\n")


def ok(result: subprocess.CompletedProcess) -> subprocess.CompletedProcess:
    """``result``, after asserting that it exited 0 (its stderr's end in the message otherwise)."""
    assert result.returncode == 0, f"{result.args[0]} exited {result.returncode}:\n{result.stderr[-3000:]}"
    return result


def refused(result: subprocess.CompletedProcess) -> str:
    """The one line a refused run prints, after asserting exit status 2 and no traceback."""
    assert result.returncode == 2, f"{result.args[0]} exited {result.returncode}:\n{result.stderr[-3000:]}"
    lines = [line for line in result.stderr.splitlines() if line.strip() and "Warning" not in line
             and not line.startswith("  ")]
    assert "Traceback" not in result.stderr and len(lines) == 1, result.stderr
    return lines[0]


def example(name: str) -> str:
    """The bundled recording ``name`` (an absolute path)."""
    return str(EXAMPLES / name)


def truth(name: str) -> dict:
    """The truth file of the bundled recording ``name``."""
    return json.loads((EXAMPLES / f"{name}.truth.json").read_text())


def write_authors_folder(recording: str, root: Path, centre=(0.31, -0.12), tip_height=0.05) -> Path:
    """The DiffStir authors' layout (data/traj.npy, data/force.npy, config/arguments.json) of a bundled 1 kHz
    recording: its positions about the cup axis at ``centre`` [m] with the rod's tip at ``tip_height`` [m] in the
    middle column, its readings, and its rig as their scene_information."""
    rec = load_recording(EXAMPLES / recording)
    level = np.full(rec.t.size, tip_height)
    traj = np.stack([rec.y + centre[1], level, rec.x + centre[0]], axis=1)  # (y, z, x): x and y follow z cyclically
    (root / "data").mkdir(parents=True)
    (root / "config").mkdir()
    np.save(root / "data" / "traj.npy", traj)
    np.save(root / "data" / "force.npy", rec.force)
    fill = rec.cup.resolved_fill_height()
    scene = {"container_diameter": 2 * rec.cup.radius, "liquid_height": fill,
             "operator_bottom_height": fill - rec.rod.immersion_depth, "operator_radius": rec.rod.radius,
             "liquid_density": truth(recording)["fluid"]["density"]}
    (root / "config" / "arguments.json").write_text(json.dumps({"scene_information": scene}, indent=1))
    return root
