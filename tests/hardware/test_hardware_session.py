"""Recording sessions against emulated devices: a clean session, and faults during the stir (device gone,
stall, garbage, Ctrl-C, dropped rod), each leaving a valid recording with everything received; resuming."""

from __future__ import annotations

import hashlib
import math
import os
import signal
import threading

import numpy as np
import pytest
import yaml

from diffstir.hardware import (
    DeviceDisconnected, GripperError, HardwareWarning, Pose, ReplayArm, SensorStalled, SerialADC, Session,
    read_session,
)
from diffstir.hardware.emulators import nominal_calibration
from diffstir.hardware.gripper import AG95Gripper
from diffstir.hardware.session import POSE_GAP_FACTOR
from diffstir.recording import load_recording
from diffstir.trajectory import circle, stationary

pytestmark = [pytest.mark.timeout(20), pytest.mark.filterwarnings("ignore::diffstir.hardware.HardwareWarning"),
              pytest.mark.filterwarnings("ignore::diffstir.recording.RecordingWarning")]
RATE = 400.0  # Hz, emulated ADC
FLUSH = 1.0  # s
TRUE_FORCE = lambda t: 1.0 + 0.05 * math.sin(2 * math.pi * t)  # noqa: E731, N: preload plus a stirring force


def _session(tmp_path, rig, adc, **kwargs) -> Session:
    return Session(tmp_path / "runs", adc=adc, arm=ReplayArm(rate=125), calibration=nominal_calibration(),
                   flush_interval=FLUSH, **rig, **kwargs)


def _table(path) -> dict[str, np.ndarray]:
    data = np.genfromtxt(path, delimiter=",", names=True)
    return {name: np.atleast_1d(data[name]) for name in data.dtype.names}


def _check_prefix(session: Session, emulator, recording, *, to_the_end: bool = False) -> None:
    """stir-adc.csv holds every sample the emulator sent during the stir, in order (``to_the_end``: up to the
    last one it sent, for a device that vanished or stalled); the recording's rows are a contiguous run of them
    that stops at most one flush interval of samples before the last one received."""
    adc = _table(session.path / "stir-adc.csv")
    sent = np.array(emulator.sent)
    first = int(np.flatnonzero(sent[:, 0] == round(adc["t_device"][0] * 1e6) % 2**32)[0])
    sent = sent[first:first + adc["raw"].size]
    assert adc["raw"].size > 0 and np.array_equal(adc["raw"], sent[:, 1])
    assert np.allclose(np.round(adc["t_device"] * 1e6) % 2**32, sent[:, 0])
    assert not to_the_end or first + adc["raw"].size == len(emulator.sent)
    raw = recording.raw
    matches = [k for k in range(adc["raw"].size - raw.size + 1) if np.array_equal(adc["raw"][k:k + raw.size], raw)]
    assert matches, "the recording's raw column is not a run of the samples received"
    assert adc["raw"].size - (matches[-1] + raw.size) <= RATE * FLUSH


def test_clean_session(tmp_path, rig, adc_emulator, gripper_emulator):
    emulator = adc_emulator(sample_rate=RATE, force=TRUE_FORCE)
    gripper_emu = gripper_emulator(rod_position=380)
    with SerialADC(emulator.port) as adc, AG95Gripper(gripper_emu.port, timeout=0.1) as gripper, \
            _session(tmp_path, rig, adc, gripper=gripper, fluid="water", temperature=21.0) as session:
        session.grip(40)
        baseline = session.dry_run(stationary(0.5, position=(0.02, 0.0)))
        session.measure_density(0.52, 0.13, 0.08)
        path = session.stir(circle(0.02, 0.2, 1.2, ramp_time=0.1))
    meta = read_session(session.path)
    assert session.path.name == "run-1" and meta["status"] == "complete"
    assert [meta["steps"][s]["status"] for s in ("grip", "dry_run", "density", "stir")] == ["done"] * 4
    assert meta["steps"]["grip"]["position"] == 380
    assert meta["steps"]["density"]["density"] == pytest.approx(0.39 / (math.pi * 0.0125**2 * 0.08 * 9.81))
    assert baseline.mean == pytest.approx(1.0, abs=0.03)
    rec = load_recording(path)
    assert rec.complete and rec.fluid == "water" and rec.density.rod_weight == 0.52
    assert rec.t[0] == 0 and rec.t.size == meta["steps"]["stir"]["rows"] == pytest.approx(RATE * 1.2, rel=0.1)
    assert meta["steps"]["stir"]["largest_pose_gap"] < POSE_GAP_FACTOR / 125
    assert np.hypot(rec.x, rec.y) == pytest.approx(0.02, abs=5e-4)  # chords between poses: < 2.5 %
    expected = nominal_calibration().force(rec.raw) - baseline.mean
    assert rec.force == pytest.approx(expected, abs=1e-9)
    assert np.max(np.abs(rec.force + baseline.mean - 1.0)) < 0.08  # the stirring force, within noise
    _check_prefix(session, emulator, rec)


@pytest.mark.parametrize("fault, error, match", [
    (dict(disappear_after=150), DeviceDisconnected, "serial port failed"),
    (dict(stall_after=150), SensorStalled, "no valid sample for 0.3 s"),
])
def test_fault_mid_stir_leaves_a_partial_recording(tmp_path, rig, adc_emulator, fault, error, match):
    emulator = adc_emulator(sample_rate=RATE, force=TRUE_FORCE, **fault)
    with SerialADC(emulator.port, stall_timeout=0.3) as adc, pytest.raises(error, match=match):
        with _session(tmp_path, rig, adc) as session:
            session.stir(circle(0.02, 0.2, 5.0, ramp_time=0.1))
    rec = load_recording(session.path / "stir")
    assert not rec.complete and error.__name__ in rec.partial_reason
    assert 100 < rec.t.size <= 150
    _check_prefix(session, emulator, rec, to_the_end=True)
    meta = read_session(session.path)
    assert meta["status"] == "failed" and meta["steps"]["stir"]["status"] == "failed"
    assert error.__name__ in meta["reason"] and meta["steps"]["stir"]["rows"] == rec.t.size


def test_garbage_and_partial_lines_are_survived(tmp_path, rig, adc_emulator):
    emulator = adc_emulator(sample_rate=RATE, force=TRUE_FORCE, garbage_every=25, partial_every=40)
    with SerialADC(emulator.port) as adc, _session(tmp_path, rig, adc) as session, \
            pytest.warns(HardwareWarning, match="without a dry run"):
        session.stir(circle(0.02, 0.2, 1.2, ramp_time=0.1))
    rec = load_recording(session.path / "stir")
    steps = read_session(session.path)["steps"]
    assert rec.complete and steps["stir"]["skipped_lines"] >= emulator.emitted // 25
    _check_prefix(session, emulator, rec)


@pytest.fixture
def ctrl_c_raises():
    """SIGINT raises KeyboardInterrupt for the test, even where the runner was started with it ignored (as a
    shell starts a background job); the previous handler comes back afterwards."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def test_ctrl_c_mid_stir(tmp_path, rig, adc_emulator, ctrl_c_raises):
    emulator = adc_emulator(sample_rate=RATE, force=TRUE_FORCE)
    timer = threading.Timer(0.6, os.kill, (os.getpid(), signal.SIGINT))
    with SerialADC(emulator.port) as adc, pytest.raises(KeyboardInterrupt):
        with _session(tmp_path, rig, adc) as session:
            timer.start()
            session.stir(circle(0.02, 0.2, 10.0, ramp_time=0.1))
    timer.join()
    rec = load_recording(session.path / "stir")
    assert not rec.complete and "KeyboardInterrupt" in rec.partial_reason and rec.t.size > 100
    meta = read_session(session.path)
    assert meta["status"] == "interrupted" and meta["steps"]["stir"]["status"] == "interrupted"
    _check_prefix(session, emulator, rec)


def test_dropped_rod_stops_the_stir(tmp_path, rig, adc_emulator, gripper_emulator):
    emulator, gripper_emu = adc_emulator(sample_rate=RATE), gripper_emulator()
    timer = threading.Timer(0.5, gripper_emu.drop)
    with SerialADC(emulator.port) as adc, AG95Gripper(gripper_emu.port, timeout=0.1) as gripper, \
            pytest.raises(GripperError, match="dropped"):
        with _session(tmp_path, rig, adc, gripper=gripper) as session:
            session.grip()
            timer.start()
            session.stir(circle(0.02, 0.2, 10.0, ramp_time=0.1))
    rec = load_recording(session.path / "stir")
    assert not rec.complete and "GripperError" in rec.partial_reason


def _digest(directory) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(directory.rglob("*")) if p.is_file()}


def test_resume_never_touches_the_earlier_session(tmp_path, rig, adc_emulator):
    emulator = adc_emulator(sample_rate=RATE, force=TRUE_FORCE, stall_after=500)
    with SerialADC(emulator.port, stall_timeout=0.3) as adc, pytest.raises(SensorStalled):
        with _session(tmp_path, rig, adc) as first:
            first.dry_run(stationary(0.3, position=(0.02, 0.0)))
            first.measure_density(0.52, 0.13, 0.08)
            first.stir(circle(0.02, 0.2, 5.0, ramp_time=0.1))
    before = _digest(first.path)
    emulator = adc_emulator(sample_rate=RATE, force=TRUE_FORCE)
    with SerialADC(emulator.port) as adc:
        with _session(tmp_path, rig, adc, resume=first.path) as second:
            assert second.baseline == first.baseline and second.density == first.density
            second.stir(circle(0.02, 0.2, 1.2, ramp_time=0.1))
        with _session(tmp_path, rig, adc, resume=second.path) as third:
            assert third.baseline.mean == first.baseline.mean
    assert _digest(first.path) == before
    assert (second.path.name, third.path.name) == ("run-1.resume-1", "run-1.resume-2")
    meta = read_session(second.path)
    assert meta["resumes"] == "../run-1" and meta["steps"]["dry_run"]["status"] == "reused"
    assert meta["steps"]["density"]["from"] == "../run-1" and meta["status"] == "complete"
    assert read_session(third.path)["steps"]["dry_run"]["from"] == "../run-1"
    assert load_recording(second.path / "stir").density == first.density


def test_sessions_are_numbered_and_the_wall_is_checked(tmp_path, rig, adc_emulator):
    emulator = adc_emulator(sample_rate=RATE)
    with SerialADC(emulator.port) as adc:
        names = [_session(tmp_path, rig, adc, name="oil").path.name for _ in range(2)]
        with pytest.raises(ValueError, match="hit the wall"):
            _session(tmp_path, rig, adc).stir(circle(0.035, 0.2, 1.0))
    assert names == ["oil-1", "oil-2"]
    assert yaml.safe_load((tmp_path / "runs" / "oil-1" / "session.yaml").read_text())["status"] == "running"


class _StutteringArm(ReplayArm):
    """A replay arm whose link drops every pose stamped within ``gap`` [s] after ``at`` [s] of the programme."""

    def __init__(self, at: float, gap: float) -> None:
        super().__init__(rate=125)
        self.at, self.gap = at, gap

    def follow(self, trajectory, on_pose, stop=None):
        first = []

        def forward(pose: Pose) -> None:
            first.append(first[0] if first else pose.t)
            if not self.at < pose.t - first[0] < self.at + self.gap:
                on_pose(pose)

        super().follow(trajectory, forward, stop)


def test_a_gap_in_the_poses_is_warned_about_and_kept(tmp_path, rig, adc_emulator):
    emulator = adc_emulator(sample_rate=RATE, force=TRUE_FORCE)
    with SerialADC(emulator.port) as adc, pytest.warns(HardwareWarning, match=r"no pose for 0\.1\d\d s"), \
            Session(tmp_path / "runs", adc=adc, arm=_StutteringArm(at=0.5, gap=0.11),
                    calibration=nominal_calibration(), flush_interval=FLUSH, **rig) as session:
        session.stir(circle(0.02, 0.2, 1.2, ramp_time=0.1))
    gap = read_session(session.path)["steps"]["stir"]["largest_pose_gap"]
    assert 0.11 <= gap <= 0.11 + 2 / 125  # the dropped span plus at most the two interval ends
