"""The diffstir-record Hydra app: every config group composes; a whole session with emulated backends runs
in-process; in a subprocess, Ctrl-C and a hard kill mid-stir both leave a valid partial recording."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate
from omegaconf import OmegaConf

from diffstir.apps import record
from diffstir.hardware import ReplayArm, Session, read_session
from diffstir.lab import programme_path
from diffstir.planning import PlanSettings, Prior
from diffstir.planning.calibration import SHIPPED, Calibration
from diffstir.planning.result import PATH_RATE
from diffstir.planning.sequential import StirSoFar, first_stir, next_segment
from diffstir.recording import CupGeometry, RodGeometry, SensorSpec, load_recording

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


class _CommandedArm(ReplayArm):
    """A replay arm that keeps every path it is told to follow."""

    def __init__(self) -> None:
        super().__init__()
        self.followed = []

    def follow(self, trajectory, on_pose, stop=None):
        self.followed.append(trajectory)
        return super().follow(trajectory, on_pose, stop)


def _plateaus(trajectory, least: float = 0.3) -> list[float]:
    """The speeds [m/s] a circular path holds for at least ``least`` seconds, in time order: the radius times the
    rate of its polar angle, exact where the angle grows linearly."""
    angle = np.unwrap(np.arctan2(trajectory.xy[:, 1], trajectory.xy[:, 0]))
    radius = np.linalg.norm(trajectory.xy, axis=-1)
    speed = np.round(radius[1:] * np.diff(angle) / np.diff(trajectory.t), 6)
    values, first, counts = np.unique(speed, return_index=True, return_counts=True)
    held = counts * (trajectory.t[1] - trajectory.t[0]) >= least
    return [float(v) for _, v in sorted(zip(first[held], values[held]))]


def _flow_curve_of(law, calibration, arm: _CommandedArm, log_std: float = 0.05):
    """A stand-in for the flow-curve analysis: one point per speed the arm held in each stir so far, at the rig's
    shear rate (the plan's calibration) and ``law``'s viscosity there [Pa·s], with the standard error ``log_std``
    of ln η; the stir's length is the sum of the paths' durations."""
    def analyse(recordings: list[Path], out: Path) -> StirSoFar:
        assert len(recordings) == len(arm.followed) and all(load_recording(r).complete for r in recordings)
        out.mkdir()
        speeds = [u for path in arm.followed for u in _plateaus(path)]
        rates = [calibration.shear_rate(u) for u in speeds]
        return StirSoFar(tuple(speeds), tuple(rates), tuple(law(np.array(rates)).tolist()),
                         (log_std,) * len(speeds), sum(path.duration for path in arm.followed))
    return analyse


@pytest.mark.timeout(120)
@pytest.mark.parametrize("fluid", ["weakly_thinning", "newtonian"])
def test_the_sequential_mode_stirs_what_the_plan_calls_for_until_decided_or_the_budget_is_spent(tmp_path, fluid):
    """A weakly thinning fluid (power law, K = 0.5 Pa·sⁿ, n = 0.9) is not decided by the first stir: its two
    speeds, a factor 4 apart, leave its points 0.14 in ln η apart against their 0.05 standard errors, and the
    Newtonian law ~3 behind in BIC. The loop then stirs the speed the plan calls for after each analysis, for its
    duration, until the family is decided or no stir fits the 8 s budget. Points on a constant viscosity (0.5
    Pa·s) end in the Newtonian family."""
    laws = {"weakly_thinning": lambda g: 0.5 * g ** (0.9 - 1), "newtonian": lambda g: np.full_like(g, 0.5)}
    settings, prior = PlanSettings(), Prior()
    calibration = Calibration.from_dict(json.loads(next(SHIPPED.glob("calibration-*.json")).read_text()))
    cfg = _compose(EMULATED + [f"out={tmp_path}", "density.skip=true", "hardware/gripper=none"])
    arm = _CommandedArm()
    with instantiate(cfg.hardware.adc) as adc:
        session = Session(tmp_path, adc=adc, arm=arm, calibration=adc.calibration,
                          cup=CupGeometry(0.0425, fill_volume=738e-6), rod=RodGeometry(0.0125, 0.080),
                          sensor=SensorSpec("component", axis=(1.0, 0.0), resolution=0.005, sample_rate=200))
        noises = []

        def next_stir(so_far, noise):  # as record.sequential_planner's: planned with the dry run's noise
            noises.append(noise)
            return next_segment(so_far, calibration, prior, replace(settings, noise=noise))

        with session:
            first = first_stir(settings)
            session.dry_run(record._dry_programme(programme_path(first, PATH_RATE), "mean", 0.5, 0.10))
            arm.followed.clear()  # the stirs' paths alone
            steps = record.stir_sequentially(session, first, _flow_curve_of(laws[fluid], calibration, arm),
                                             next_stir)
    assert noises == [session.baseline.std] * len(steps) and session.baseline.std > 0
    meta = read_session(session.path)
    assert meta["status"] == "complete" and meta["sequence"] == steps and len(arm.followed) == len(steps)
    for k, (step, path) in enumerate(zip(steps, arm.followed)):
        assert step["stir"] == f"stir-{k + 1}" and meta["steps"][step["stir"]]["status"] == "done"
        assert json.loads((session.path / step["analysis"] / "next.json").read_text()) == {
            key: value for key, value in step.items() if key not in ("stir", "programme", "analysis")}
        segments = step["programme"]["segments"]
        assert _plateaus(path) == pytest.approx([s["speed"] for s in segments], abs=2e-6)
        assert path.duration == pytest.approx(sum(s["duration"] for s in segments), abs=1e-9)
        if k > 0:  # the stir called for, from where the last one left the rod
            assert segments == [{"speed": steps[k - 1]["next"]["speed"], "duration": steps[k - 1]["next"]["duration"]}]
            np.testing.assert_allclose(path.xy[0], arm.followed[k - 1].xy[-1], atol=1e-12)
    last = steps[-1]
    assert all(s["next"] is not None and not s["decided"] for s in steps[:-1]) and last["next"] is None
    assert last["elapsed"] <= settings.budget
    assert last["family"] == {"weakly_thinning": "shear_thinning", "newtonian": "newtonian"}[fluid]
    assert last["decided"] or last["candidates"] == {}  # decided, or no stir fits the budget left
    assert len(steps) >= (2 if fluid == "weakly_thinning" else 1)
