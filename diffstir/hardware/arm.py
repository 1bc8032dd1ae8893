"""Robot arms that move the rod: follow a stirring trajectory and report the rod's pose as they go.

Poses are in the cup frame (origin on the cup's axis, z up; ``z`` is the rod's vertical displacement from its
rest immersion) and stamped with the host's monotonic clock (``time.monotonic()``), the clock the ADC's
samples are aligned to. Backends:

- ``ReplayArm``: plays a trajectory in real time (optionally faster) and reports the commanded poses; the
  emulated arm, and a way to replay a recorded motion.
- ``URArm``: Universal Robots through ur-rtde (``servoL``); poses from ``getActualTCPPose``, stamped with the
  controller's clock aligned to the host's (``ClockAligner``).
- ``XArmArm``: UFactory xArm through xArm-Python-SDK (servo mode 1); poses stamped on arrival.

The real backends import their package when constructed, never at import time.
"""

from __future__ import annotations

import importlib
import itertools
import math
import threading
import time
from abc import ABC, abstractmethod
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from diffstir.hardware.clock import ClockAligner
from diffstir.hardware.errors import HardwareError, MissingExtraError
from diffstir.trajectory import Trajectory


@dataclass(frozen=True)
class Pose:
    """The rod's axis at host time ``t`` [s]: ``x``, ``y`` [m] in the cup frame, ``z`` [m] from rest immersion."""

    t: float
    x: float
    y: float
    z: float


class Arm(ABC):
    """Moves the rod along a trajectory."""

    name = "arm"

    @abstractmethod
    def follow(self, trajectory: Trajectory, on_pose: Callable[[Pose], None],
               stop: threading.Event | None = None) -> None:
        """Move the rod along ``trajectory`` (its times taken relative to its first sample), calling
        ``on_pose`` for every pose the arm reports; returns at the end or soon after ``stop`` is set."""

    def close(self) -> None:
        """Release the connection."""

    def __enter__(self) -> "Arm":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class ReplayArm(Arm):
    """An ideal arm: reports the trajectory's own poses at ``rate`` [Hz], in real time divided by ``speedup``.

    The arm keeps its own clock: pose ``i`` is stamped ``t0 + i / rate`` and placed at programme time
    ``i * speedup / rate``, so a host thread that is scheduled late delivers the poses it missed in a burst
    (as a buffered controller would) instead of leaving a gap in the pose stream.
    """

    name = "replay arm"

    def __init__(self, rate: float = 125.0, speedup: float = 1.0) -> None:
        if rate <= 0 or speedup <= 0:
            raise ValueError(f"ReplayArm: rate = {rate} Hz and speedup = {speedup} must be positive")
        self.rate, self.speedup = rate, speedup

    def follow(self, trajectory, on_pose, stop=None):
        stop = stop or threading.Event()
        t0 = time.monotonic()
        for i in itertools.count():
            stamp = t0 + i / self.rate
            if stop.wait(max(0.0, stamp - time.monotonic())):
                return
            tau = min(i * self.speedup / self.rate, trajectory.duration)
            xy, z, _ = trajectory.poses(trajectory.t[0] + tau)
            on_pose(Pose(stamp, float(xy[0]), float(xy[1]), float(z)))
            if tau >= trajectory.duration:
                return


@dataclass(frozen=True)
class CupFrame:
    """The cup frame in the robot's base frame: ``origin`` [m] is the tool centre point's position with the
    rod on the cup's axis at rest immersion; ``yaw`` [rad] turns the cup's x axis about the base's z axis."""

    origin: tuple[float, float, float]
    yaw: float = 0.0

    def to_base(self, x, y, z) -> np.ndarray:
        """Base-frame positions [m] of cup-frame positions [m]."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return np.stack([self.origin[0] + c * np.asarray(x) - s * np.asarray(y),
                         self.origin[1] + s * np.asarray(x) + c * np.asarray(y),
                         self.origin[2] + np.asarray(z)], axis=-1)

    def from_base(self, p) -> tuple[float, float, float]:
        """Cup-frame position [m] of a base-frame position ``p`` [m]."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        dx, dy, dz = p[0] - self.origin[0], p[1] - self.origin[1], p[2] - self.origin[2]
        return c * dx + s * dy, -s * dx + c * dy, dz


def _require(module: str, package: str, extra: str, backend: str):
    """Import an optional backend's module or say what to install."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise MissingExtraError(f"{backend} needs the {package!r} package (import {module} failed: {exc}); "
                                f"install it with: pip install 'diffstir[{extra}]'  (or: pip install {package})") \
            from exc


def _commanded(trajectory: Trajectory, rate: float, max_speed: float, max_acceleration: float, backend: str):
    """The trajectory resampled at ``rate`` [Hz] as cup-frame points [m], after checking the arm's limits."""
    if np.ptp(trajectory.angle) > 0:
        raise ValueError(f"{backend}: the trajectory turns the rod about its own axis; only translations are "
                         "supported by this backend")
    times = trajectory.t[0] + np.arange(int(math.ceil(trajectory.duration * rate)) + 1) / rate
    times[-1] = min(times[-1], trajectory.t[-1])
    xy, z, _ = trajectory.poses(times)
    points = np.column_stack([xy, z])
    v = np.gradient(points, times, axis=0)
    speed = float(np.max(np.linalg.norm(v, axis=1)))
    accel = float(np.max(np.linalg.norm(np.gradient(v, times, axis=0), axis=1)))
    if speed > max_speed or accel > max_acceleration:
        raise ValueError(f"{backend}: the trajectory reaches {speed:.3f} m/s and {accel:.2f} m/s²; the limits "
                         f"are max_speed = {max_speed} m/s and max_acceleration = {max_acceleration} m/s²")
    return points


class URArm(Arm):
    """A Universal Robots arm through ur-rtde (``pip install ur-rtde``).

    Args:
        host: the controller's IP address.
        frame: where the cup frame sits in the robot's base frame.
        orientation: the tool's fixed orientation, a rotation vector in the base frame [rad].
        rate: servo rate [Hz] (500 on e-series, 125 on CB3).
        lookahead_time: servoL look-ahead [s] (0.03-0.2; larger is smoother and lags more).
        gain: servoL proportional gain (100-2000).
        max_speed: refuse trajectories faster than this [m/s].
        max_acceleration: refuse trajectories accelerating more than this [m/s²].
        approach_speed: speed of the linear move to the trajectory's start [m/s].
    """

    name = "UR arm"

    def __init__(self, host: str, frame: CupFrame, *, orientation=(0.0, math.pi, 0.0), rate: float = 500.0,
                 lookahead_time: float = 0.1, gain: float = 300.0, max_speed: float = 0.25,
                 max_acceleration: float = 2.0, approach_speed: float = 0.05) -> None:
        control = _require("rtde_control", "ur-rtde", "ur", "URArm")
        receive = _require("rtde_receive", "ur-rtde", "ur", "URArm")
        self.host, self.frame, self.orientation = host, frame, list(map(float, orientation))
        self.rate, self.lookahead_time, self.gain = rate, lookahead_time, gain
        self.max_speed, self.max_acceleration, self.approach_speed = max_speed, max_acceleration, approach_speed
        try:
            self._control = control.RTDEControlInterface(host)
            self._receive = receive.RTDEReceiveInterface(host)
        except RuntimeError as exc:
            raise HardwareError(f"UR arm at {host}: cannot connect through RTDE: {exc}") from exc

    def follow(self, trajectory, on_pose, stop=None):
        points = _commanded(trajectory, self.rate, self.max_speed, self.max_acceleration, "URArm")
        targets = [list(p) + self.orientation for p in self.frame.to_base(*points.T).tolist()]
        self._control.moveL(targets[0], self.approach_speed, 0.5)  # 0.5 m/s² ramps to a gentle approach
        clock, last = ClockAligner(), None
        try:
            for target in targets:
                cycle = self._control.initPeriod()
                self._control.servoL(target, 0.0, 0.0, 1.0 / self.rate, self.lookahead_time, self.gain)
                stamp, arrived = self._receive.getTimestamp(), time.monotonic()
                if stamp != last:
                    last = stamp
                    clock.add(stamp, arrived)
                    x, y, z = self.frame.from_base(self._receive.getActualTCPPose())
                    on_pose(Pose(float(clock.fit().to_host(stamp)), x, y, z))
                if stop is not None and stop.is_set():
                    break
                self._control.waitPeriod(cycle)
        finally:
            self._control.servoStop()

    def close(self) -> None:
        self._control.stopScript()
        self._receive.disconnect()


class XArmArm(Arm):
    """A UFactory xArm through xArm-Python-SDK (``pip install xarm-python-sdk``); it works in mm, converted here.

    Args:
        host: the controller's IP address.
        frame: where the cup frame sits in the robot's base frame.
        orientation: the tool's fixed roll, pitch, yaw [rad].
        rate: servo rate [Hz] (at most 250).
        max_speed, max_acceleration: refuse trajectories beyond these [m/s, m/s²].
        approach_speed: speed of the move to the trajectory's start [m/s].
    """

    name = "xArm"

    def __init__(self, host: str, frame: CupFrame, *, orientation=(math.pi, 0.0, 0.0), rate: float = 100.0,
                 max_speed: float = 0.25, max_acceleration: float = 2.0, approach_speed: float = 0.05) -> None:
        wrapper = _require("xarm.wrapper", "xarm-python-sdk", "xarm", "XArmArm")
        self.host, self.frame, self.orientation = host, frame, list(map(float, orientation))
        self.rate, self.max_speed, self.max_acceleration = rate, max_speed, max_acceleration
        self.approach_speed = approach_speed
        self._arm = wrapper.XArmAPI(host, is_radian=True)
        self._check(self._arm.motion_enable(enable=True), "motion_enable")

    def _check(self, code, what: str) -> None:
        if code != 0:
            raise HardwareError(f"xArm at {self.host}: {what} returned error code {code}")

    def follow(self, trajectory, on_pose, stop=None):
        points = _commanded(trajectory, self.rate, self.max_speed, self.max_acceleration, "XArmArm")
        targets_mm = (self.frame.to_base(*points.T) * 1e3).tolist()
        self._check(self._arm.set_mode(0), "set_mode(0)")
        self._check(self._arm.set_state(0), "set_state(0)")
        x, y, z = targets_mm[0]
        self._check(self._arm.set_position(x=x, y=y, z=z, roll=self.orientation[0], pitch=self.orientation[1],
                                           yaw=self.orientation[2], speed=self.approach_speed * 1e3, wait=True),
                    "set_position")
        self._check(self._arm.set_mode(1), "set_mode(1)")
        self._check(self._arm.set_state(0), "set_state(0)")
        t0 = time.monotonic()
        try:
            for i, target in enumerate(targets_mm):
                self._check(self._arm.set_servo_cartesian(target + self.orientation), "set_servo_cartesian")
                code, pose = self._arm.get_position()
                self._check(code, "get_position")
                on_pose(Pose(time.monotonic(), *self.frame.from_base([v * 1e-3 for v in pose[:3]])))
                if stop is not None and stop.is_set():
                    break
                time.sleep(max(0.0, t0 + (i + 1) / self.rate - time.monotonic()))
        finally:
            self._arm.set_mode(0)
            self._arm.set_state(0)

    def close(self) -> None:
        self._arm.disconnect()


def load_trajectory(path) -> Trajectory:
    """A trajectory from a CSV file with a header and columns ``t`` [s], ``x``, ``y`` and optionally ``z`` [m];
    lines starting with ``#`` are comments, so a recording's stir.csv replays its own motion."""
    lines = [line for line in Path(path).read_text().splitlines() if line.strip() and not line.startswith("#")]
    names = [name.strip() for name in lines[0].split(",")] if lines else []
    missing = [c for c in ("t", "x", "y") if c not in names]
    if missing:
        raise ValueError(f"trajectory file {path}: missing column(s) {missing}; has {names}")
    table = dict(zip(names, np.loadtxt(lines[1:], delimiter=",", ndmin=2).T))
    t = table["t"]
    return Trajectory(t - t[0], np.column_stack([table["x"], table["y"]]), table.get("z", 0.0), 0.0)
