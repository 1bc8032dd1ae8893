"""Arms: the replay backend in real time, trajectory files, and the UR and xArm backends against stand-ins of
their SDKs (the real packages are optional extras)."""

from __future__ import annotations

import math
import sys
import threading
import time
import types

import numpy as np
import pytest

from diffstir.hardware import CupFrame, MissingExtraError, ReplayArm, URArm, XArmArm, load_trajectory
from diffstir.trajectory import circle

pytestmark = pytest.mark.timeout(10)
FRAME = CupFrame(origin=(0.4, -0.1, 0.25), yaw=math.radians(30))


def test_replay_plays_in_real_time_with_speedup():
    trajectory = circle(0.02, 0.1, 1.0, ramp_time=0.2)
    poses = []
    t0 = time.monotonic()
    ReplayArm(rate=100, speedup=4).follow(trajectory, poses.append)
    elapsed = time.monotonic() - t0
    assert 0.24 < elapsed < 0.6
    assert 15 <= len(poses) <= 27 and all(b.t > a.t for a, b in zip(poses, poses[1:]))
    end = trajectory.xy[-1]
    assert (poses[-1].x, poses[-1].y) == pytest.approx(tuple(end))
    for p in poses:  # each reported pose is the trajectory's at (t - t0) * speedup
        xy, _, _ = trajectory.poses((p.t - poses[0].t) * 4)
        assert (p.x, p.y) == pytest.approx(tuple(xy), abs=2e-4)


def test_replay_keeps_its_own_clock_when_the_host_is_late():
    trajectory = circle(0.02, 0.1, 0.3, ramp_time=0.1)
    poses = []

    def slow_listener(pose):
        poses.append(pose)
        if len(poses) == 5:
            time.sleep(0.1)  # the host thread is late by 10 pose intervals

    ReplayArm(rate=100).follow(trajectory, slow_listener)
    stamps = np.array([p.t for p in poses])
    assert len(poses) == 31 and np.allclose(np.diff(stamps), 0.01)
    for p in poses:
        xy, _, _ = trajectory.poses(p.t - poses[0].t)
        assert (p.x, p.y) == pytest.approx(tuple(xy), abs=1e-12)


def test_replay_stops_when_asked():
    stop, poses = threading.Event(), []
    worker = threading.Thread(target=ReplayArm().follow, args=(circle(0.02, 0.1, 30.0), poses.append, stop))
    worker.start()
    time.sleep(0.1)
    stop.set()
    worker.join(timeout=1.0)
    assert not worker.is_alive() and 2 <= len(poses) <= 20


def test_load_trajectory_from_a_stir_csv(tmp_path):
    path = tmp_path / "stir.csv"
    path.write_text("# a comment\nt,x,y,force,z\n2.0,0.01,0.0,0.1,0.0\n2.5,0.0,0.01,0.2,0.001\n3.0,-0.01,0.0,0.1,0.0\n")
    trajectory = load_trajectory(path)
    assert trajectory.t.tolist() == [0.0, 0.5, 1.0] and trajectory.z.tolist() == [0.0, 0.001, 0.0]
    (tmp_path / "bad.csv").write_text("t,x\n0,1\n1,2\n")
    with pytest.raises(ValueError, match=r"missing column\(s\) \['y'\]"):
        load_trajectory(tmp_path / "bad.csv")


def test_cup_frame_round_trip():
    base = FRAME.to_base(0.02, 0.01, -0.005)
    assert FRAME.from_base(base) == pytest.approx((0.02, 0.01, -0.005))
    assert np.linalg.norm(base[:2] - FRAME.origin[:2]) == pytest.approx(math.hypot(0.02, 0.01))


@pytest.mark.parametrize("backend, module, extra", [(URArm, "rtde_control", "ur"), (XArmArm, "xarm", "xarm")])
def test_missing_sdk_says_what_to_install(monkeypatch, backend, module, extra):
    monkeypatch.setitem(sys.modules, module, None)
    with pytest.raises(MissingExtraError, match=rf"pip install 'diffstir\[{extra}\]'"):
        backend("192.0.2.1", FRAME)


class _FakeUR:
    """Stand-in for ur-rtde's control and receive interfaces: the TCP follows servoL exactly."""

    def __init__(self, host):
        self.calls, self.pose, self.stamp = [], [0.0] * 6, 100.0

    def moveL(self, pose, speed, acceleration):
        self.calls.append(("moveL", pose))
        self.pose = list(pose)

    def servoL(self, pose, speed, acceleration, dt, lookahead, gain):
        self.calls.append(("servoL", pose))
        self.pose = list(pose)
        self.stamp += dt

    def initPeriod(self):
        return time.monotonic()

    def waitPeriod(self, start):
        pass

    def getTimestamp(self):
        return self.stamp

    def getActualTCPPose(self):
        return self.pose

    def servoStop(self):
        self.calls.append(("servoStop",))

    def stopScript(self):
        pass

    def disconnect(self):
        pass


def test_ur_backend_drives_servol_in_the_base_frame(monkeypatch):
    fake = _FakeUR("x")
    control = types.ModuleType("rtde_control")
    receive = types.ModuleType("rtde_receive")
    control.RTDEControlInterface = receive.RTDEReceiveInterface = lambda host: fake
    monkeypatch.setitem(sys.modules, "rtde_control", control)
    monkeypatch.setitem(sys.modules, "rtde_receive", receive)
    trajectory = circle(0.02, 0.05, 0.2, ramp_time=0.1)
    poses = []
    with URArm("192.0.2.1", FRAME, rate=500) as arm:
        arm.follow(trajectory, poses.append)
    kinds = [c[0] for c in fake.calls]
    assert kinds[0] == "moveL" and kinds[-1] == "servoStop" and kinds.count("servoL") == 101
    assert fake.calls[1][1][:3] == pytest.approx(list(FRAME.to_base(0.02, 0.0, 0.0)))
    assert fake.calls[1][1][3:] == pytest.approx([0.0, math.pi, 0.0])
    assert (poses[-1].x, poses[-1].y) == pytest.approx(tuple(trajectory.xy[-1]), abs=1e-9)
    assert len(poses) == 101 and all(b.t > a.t for a, b in zip(poses, poses[1:]))


def test_ur_backend_refuses_a_too_fast_trajectory(monkeypatch):
    module = types.ModuleType("rtde")
    module.RTDEControlInterface = module.RTDEReceiveInterface = _FakeUR
    monkeypatch.setitem(sys.modules, "rtde_control", module)
    monkeypatch.setitem(sys.modules, "rtde_receive", module)
    with pytest.raises(ValueError, match="max_speed = 0.25 m/s"):
        URArm("192.0.2.1", FRAME).follow(circle(0.02, 0.5, 1.0), lambda pose: None)


class _FakeXArm:
    """Stand-in for xArm-Python-SDK's XArmAPI (mm and radians); the arm follows servo targets exactly."""

    def __init__(self, host, is_radian):
        assert is_radian
        self.pose, self.modes, self.servo = [0.0] * 6, [], 0

    def motion_enable(self, enable):
        return 0

    def set_mode(self, mode):
        self.modes.append(mode)
        return 0

    def set_state(self, state):
        return 0

    def set_position(self, x, y, z, roll, pitch, yaw, speed, wait):
        self.pose = [x, y, z, roll, pitch, yaw]
        return 0

    def set_servo_cartesian(self, pose):
        self.pose, self.servo = list(pose), self.servo + 1
        return 0

    def get_position(self):
        return 0, self.pose

    def disconnect(self):
        pass


def test_xarm_backend_works_in_millimetres(monkeypatch):
    package, wrapper = types.ModuleType("xarm"), types.ModuleType("xarm.wrapper")
    wrapper.XArmAPI = _FakeXArm
    monkeypatch.setitem(sys.modules, "xarm", package)
    monkeypatch.setitem(sys.modules, "xarm.wrapper", wrapper)
    trajectory = circle(0.02, 0.05, 0.1, ramp_time=0.1)
    poses = []
    with XArmArm("192.0.2.1", FRAME, rate=200) as arm:
        arm.follow(trajectory, poses.append)
        assert arm._arm.modes == [0, 1, 0] and arm._arm.servo == 21
        assert arm._arm.pose[:3] == pytest.approx(list(FRAME.to_base(*trajectory.xy[-1], 0.0) * 1e3))
    assert (poses[-1].x, poses[-1].y, poses[-1].z) == pytest.approx((*trajectory.xy[-1], 0.0), abs=1e-9)
