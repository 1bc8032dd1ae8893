"""The diffstir-record Hydra app: every config group composes; a whole session with emulated backends runs
in-process; in a subprocess, Ctrl-C and a hard kill mid-stir both leave a valid partial recording."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate
from omegaconf import OmegaConf

from diffstir.apps import record
from diffstir.hardware import read_session
from diffstir.recording import load_recording

pytestmark = [pytest.mark.timeout(30), pytest.mark.filterwarnings("ignore::diffstir.recording.RecordingWarning")]
ROOT = Path(__file__).parents[2]
EMULATED = ["hardware/adc=emulated", "hardware/arm=replay", "hardware/gripper=emulated"]


def _compose(overrides: list[str]):
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        return compose(config_name="record", overrides=overrides)


@pytest.mark.parametrize("arm", ["ur", "xarm", "replay"])
@pytest.mark.parametrize("gripper", ["ag95", "emulated", "none"])
def test_every_backend_config_composes(arm, gripper):
    cfg = _compose([f"hardware/arm={arm}", f"hardware/gripper={gripper}", "hardware/adc=serial"])
    assert cfg.hardware.adc._target_ == "diffstir.hardware.SerialADC" and OmegaConf.is_missing(cfg.hardware.adc, "port")
    assert cfg.hardware.arm._target_.startswith("diffstir.hardware.")
    assert OmegaConf.is_missing(cfg.hardware.arm, "host") == (arm != "replay")
    assert (cfg.hardware.gripper._target_ is None) == (gripper == "none")
    assert OmegaConf.is_missing(cfg.hardware.gripper, "port") == (gripper == "ag95")


def test_emulated_backends_instantiate():
    cfg = _compose(EMULATED)
    with instantiate(cfg.hardware.adc) as adc, instantiate(cfg.hardware.gripper) as gripper:
        adc.start()
        assert adc.read().counts > 0 and gripper.status() is not None
    assert instantiate(cfg.hardware.arm).rate == 125


def test_session_in_process(tmp_path, capsys):
    cfg = _compose(EMULATED + [f"out={tmp_path}", "name=water", "dry_run.duration=0.3", "stir.duration=1.2",
                               "stir.rev_per_s=1.5", "density.rod_weight=0.5", "density.immersed_reading=0.11"])
    session = record.record(cfg)
    meta = read_session(session.path)
    assert session.path == tmp_path / "water-1" and meta["status"] == "complete"
    assert meta["config"]["stir"]["duration"] == 1.2 and meta["devices"]["adc"].startswith("EmulatedADC")
    rec = load_recording(session.path / "stir")
    assert rec.complete and rec.density.immersed_depth == 0.08 and rec.t.size > 200
    assert "Stir:" in capsys.readouterr().out


@pytest.mark.parametrize("overrides, match", [
    ([], r"density.rod_weight \(N\), density.immersed_reading \(N\) not set"),
    (["density.skip=true", "rig.rod.mesh=spoon.stl"], "a recording's rod is a cylinder"),
])
def test_config_errors_are_reported_before_any_device_moves(tmp_path, overrides, match):
    cfg = _compose(EMULATED + [f"out={tmp_path}", *overrides])
    with pytest.raises(ValueError, match=match):
        record.record(cfg)
    assert not any(tmp_path.iterdir())


def _start(tmp_path) -> subprocess.Popen:
    """The app in a subprocess, with a long stir; returns once the stir has run for about 1.5 s."""
    args = [sys.executable, "-m", "diffstir.apps.record", *EMULATED[:2], "hardware/gripper=none", f"out={tmp_path}",
            "density.skip=true", "dry_run.duration=0.2", "stir.duration=60", "stir.rev_per_s=1"]
    env = {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    proc = subprocess.Popen(args, cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    for line in proc.stdout:
        if line.startswith("Stir:"):
            break
    time.sleep(1.5)
    return proc


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGKILL], ids=["ctrl-c", "kill-9"])
def test_interrupt_or_kill_mid_stir_keeps_a_partial_recording(tmp_path, sig):
    proc = _start(tmp_path)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=10)
    session = tmp_path / "run-1"
    rec = load_recording(session / "stir")
    meta = read_session(session)
    assert not rec.complete and rec.t.size == pytest.approx(200 * rec.t[-1], abs=2)  # 200 Hz, no gaps
    if sig == signal.SIGINT:  # everything up to the interrupt is kept (the stir ran for up to 1.5 s)
        assert proc.returncode == 130 and "interrupted" in err
        assert "KeyboardInterrupt" in rec.partial_reason and meta["status"] == "interrupted"
        assert rec.t[-1] > 1.5 - 0.5
    else:  # a hard kill: at most the last flush interval (1 s) is lost, and the files still read as unfinished
        assert proc.returncode == -signal.SIGKILL
        assert rec.partial_reason == "in progress" and meta["steps"]["stir"]["status"] == "running"
        assert rec.t[-1] > 1.5 - 0.5 - 1.0
