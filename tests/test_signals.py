"""SIGINT, SIGTERM and SIGKILL to a running ``diffstir-fit``: one line, exit 128 + the signal, no process left."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

import pytest


EXAMPLE_RECORDING = Path(__file__).resolve().parents[1] / "diffstir" / "data" / "examples" / "carreau_example"
#: A fit of the bundled recording in two worker processes, long enough (about 50 s on 2 cores) to be stopped while
#: they compute.
FIT = ["workers=2", "sim.dx=0.01", "~coarse", "fit.window=0.5", "progress=false", "rectifier.checkpoint=null"]


def _children(pid: int) -> set[int]:
    """The live processes whose parent is ``pid`` (from /proc/<pid>/stat), zombies excluded."""
    found = set()
    for entry in Path("/proc").glob("[0-9]*"):
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid and fields[0] != "Z":
            found.add(int(entry.name))
    return found


def _alive(pids: set[int]) -> set[int]:
    alive = set()
    for pid in pids:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if state != "Z":
            alive.add(pid)
    return alive


def _start_fit(tmp_path: Path) -> tuple[subprocess.Popen, set[int]]:
    """``diffstir-fit`` in its own session (as a terminal's foreground job), once its workers have computed the
    first results (its checkpoint exists); returns it and its children (two workers and the multiprocessing
    resource tracker)."""
    out = tmp_path / "out"
    command = [shutil.which("diffstir-fit"), f"recording={EXAMPLE_RECORDING}", f"out={out}", *FIT]
    proc = subprocess.Popen(command, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    deadline = time.monotonic() + 180.0
    while not (out / "checkpoint.json").exists():
        assert proc.poll() is None, proc.communicate()[1][-2000:]
        assert time.monotonic() < deadline, "no checkpoint within 180 s"
        time.sleep(0.2)
    children = _children(proc.pid)
    assert len(children) == 3
    return proc, children


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads processes from /proc")
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_a_signal_ends_the_fit_in_one_line_and_leaves_no_process(tmp_path, sig):
    proc, children = _start_fit(tmp_path)
    os.killpg(proc.pid, sig)  # as a terminal's Ctrl-C reaches the whole foreground group; SIGTERM as `timeout`
    _, err = proc.communicate(timeout=10)
    assert proc.returncode == 128 + sig
    assert err.strip() == f"diffstir-fit: interrupted ({sig.name}); kept {tmp_path / 'out' / 'checkpoint.json'}"
    deadline = time.monotonic() + 5.0
    while _alive(children) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _alive(children)


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads processes from /proc")
def test_the_workers_die_with_a_killed_parent(tmp_path):
    proc, children = _start_fit(tmp_path)
    proc.kill()
    proc.wait(timeout=5)
    deadline = time.monotonic() + 5.0
    while _alive(children) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _alive(children)
    proc.communicate(timeout=10)
