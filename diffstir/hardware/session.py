"""A recording session on the rig: grip the rod, dry run (baseline), density measurement, stir.

Every step writes to disk as it goes, so a crash, a pulled cable or Ctrl-C at any moment loses at most the last
``flush_interval`` (1 s) and leaves a valid, clearly marked partial recording. A session directory is never
reused: a new session takes the first free ``<name>-<k>``, a resumed one ``<earlier>.resume-<k>``; its
session.yaml points at the session it resumes, whose directory is only read.

    run-3/
      session.yaml       steps, their status and results; rewritten atomically after every change
      dry-run-adc.csv    every valid sample of the dry run: t_device [s], t_host [s], raw [counts]
      dry-run-poses.csv  every pose the arm reported: t_host [s], x, y, z [m]
      dry-run.csv        the baseline's data: tau [s, programme time], force [N, calibrated]
      stir-adc.csv       every valid sample of the stir (as above)
      stir-poses.csv     every pose of the stir (as above)
      stir/              the recording (diffstir-recording/1): t, x, y, force, z, raw

A session of several stirs (``diffstir-record``'s sequential mode) names each: ``stir-1-adc.csv``,
``stir-1-poses.csv``, ``stir-1/`` and so on.

The stir table: ``t`` is the sensor's clock, zero at the first row. Each sample's host time h comes from the
clock alignment (``ClockAligner``); the rod's pose is interpolated linearly at h; the programme time is
tau = h - (host time of the arm's first pose); force = a G(counts) + b - baseline(tau) (``Calibration``,
``Baseline``), clipped at 0 for a one-sided sensor. Samples outside the span of the arm's poses, and samples
that saturate the divider, are only in stir-adc.csv. A gap in the arm's poses longer than ``POSE_GAP_FACTOR``
median intervals (a late host thread, a dropped packet) is warned about and kept in the step's ``largest_pose_gap``
[s]: the rod's position across it is a straight chord.
"""

from __future__ import annotations

import bisect
import collections
import contextlib
import datetime
import math
import os
import re
import statistics
import threading
import time
import warnings
from pathlib import Path
from typing import Callable

import numpy as np
import yaml

from diffstir.hardware.adc import ADC, Sample
from diffstir.hardware.arm import Arm, Pose
from diffstir.hardware.calibration import Calibration
from diffstir.hardware.clock import ClockAligner
from diffstir.hardware.errors import GripperError, HardwareError, HardwareWarning
from diffstir.hardware.filters import Baseline
from diffstir.hardware.gripper import Gripper, GripState
from diffstir.recording import CupGeometry, DensityMeasurement, RecordingWriter, RodGeometry, SensorSpec
from diffstir.trajectory import Trajectory

FORMAT = "diffstir-session/1"
SESSION_FILE = "session.yaml"
GRAVITY = 9.81  # m/s^2, as in the recording format
POSE_GAP_FACTOR = 5.0  # a pose interval this many times the median one is a gap worth a warning


class _Log:
    """An append-only CSV file (never overwriting), flushed and fsynced at least every ``flush_interval`` [s]."""

    def __init__(self, path: Path, columns: list[str], flush_interval: float) -> None:
        self._file = open(path, "x", encoding="utf-8", newline="")
        self._file.write(",".join(columns) + "\n")
        self._interval, self._last = flush_interval, time.monotonic()
        self._lock = threading.Lock()

    def write(self, *values) -> None:
        with self._lock:
            if self._file.closed:
                return
            self._file.write(",".join(map(str, values)) + "\n")
            if time.monotonic() - self._last >= self._interval:
                self._flush()

    def _flush(self) -> None:
        self._file.flush()
        os.fsync(self._file.fileno())
        self._last = time.monotonic()

    def close(self) -> None:
        with self._lock:
            if not self._file.closed:
                self._flush()
                self._file.close()

    def __enter__(self) -> "_Log":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class _Poses:
    """The arm's poses as it reports them (the arm's thread adds, the main thread interpolates)."""

    def __init__(self, log: _Log) -> None:
        self.t: list[float] = []
        self.xyz: list[tuple[float, float, float]] = []
        self._log, self._lock = log, threading.Lock()

    def add(self, pose: Pose) -> None:
        with self._lock:
            if self.t and pose.t <= self.t[-1]:
                return
            self.t.append(pose.t)
            self.xyz.append((pose.x, pose.y, pose.z))
        self._log.write(pose.t, pose.x, pose.y, pose.z)

    def at(self, h: float) -> tuple[float, float, float] | str:
        """Pose at host time ``h`` [s], or ``"before"`` / ``"after"`` the span reported so far."""
        with self._lock:
            n = len(self.t)
        if n == 0 or h > self.t[n - 1]:
            return "after"
        if h < self.t[0]:
            return "before"
        i = min(bisect.bisect_right(self.t, h, 0, n), n - 1)
        if i == 0:
            return self.xyz[0]
        w = (h - self.t[i - 1]) / (self.t[i] - self.t[i - 1])
        a, b = self.xyz[i - 1], self.xyz[i]
        return tuple(a[k] + w * (b[k] - a[k]) for k in range(3))

    def largest_gap(self) -> tuple[float, float, float]:
        """The longest interval between poses [s], the programme time it starts at [s], and the median
        interval [s]; zeros with fewer than two poses."""
        with self._lock:
            t = list(self.t)
        if len(t) < 2:
            return 0.0, 0.0, 0.0
        gaps = [b - a for a, b in zip(t, t[1:])]
        i = max(range(len(gaps)), key=gaps.__getitem__)
        return gaps[i], t[i] - t[0], statistics.median(gaps)


def _write_yaml_atomic(path: Path, data: dict) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", encoding="utf-8") as f:
        yaml.safe_dump(data, f, sort_keys=False)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    fd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _new_dir(parent: Path, stem: str) -> Path:
    """Create and return the first free ``<stem>-<k>`` (k = 1, 2, ...) in ``parent``; mkdir makes it race-free."""
    parent.mkdir(parents=True, exist_ok=True)
    for k in range(1, 100_000):
        path = parent / f"{stem}-{k}"
        try:
            path.mkdir()
            return path
        except FileExistsError:
            continue
    raise FileExistsError(f"{parent}: no free session name {stem}-<k>")


def read_session(path) -> dict:
    """The session.yaml of the session directory ``path``, checking its format."""
    path = Path(path)
    meta = yaml.safe_load((path / SESSION_FILE).read_text()) if (path / SESSION_FILE).exists() else None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise ValueError(f"{path}: not a session directory (no {SESSION_FILE} with format {FORMAT!r})")
    return meta


class Session:
    """One recording session in a new directory under ``root`` (module docstring).

    Args:
        root: directory holding the sessions.
        adc: the force sensor's ADC.
        arm: the arm holding the rod.
        calibration: counts to force [N].
        cup, rod, sensor: the rig and the sensor, as the recording states them.
        gripper: the gripper holding the rod, or None.
        name: stem of the session's directory name (``<name>-<k>``).
        fluid, temperature: labels for the recording (temperature in degrees Celsius).
        resume: an earlier session directory to resume: its baseline and density are reused when they were
            completed there, and the new directory is ``<earlier>.resume-<k>``.
        flush_interval: longest time between fsyncs of every file [s].
        latency: known minimum latency from a sample's conversion to its arrival [s] (clock alignment).
        config: free-form settings stored in session.yaml (the app's resolved config).
    """

    def __init__(self, root, *, adc: ADC, arm: Arm, calibration: Calibration, cup: CupGeometry,
                 rod: RodGeometry, sensor: SensorSpec, gripper: Gripper | None = None, name: str = "run",
                 fluid: str | None = None, temperature: float | None = None, resume=None,
                 flush_interval: float = 1.0, latency: float = 0.0, config: dict | None = None) -> None:
        self.adc, self.arm, self.gripper, self.calibration = adc, arm, gripper, calibration
        self.cup, self.rod, self.sensor, self.fluid, self.temperature = cup, rod, sensor, fluid, temperature
        self.flush_interval, self.latency = flush_interval, latency
        self.baseline: Baseline | None = None
        self.density: DensityMeasurement | None = None
        earlier = Path(resume) if resume is not None else None
        earlier_meta = read_session(earlier) if earlier is not None else None
        if earlier is not None:
            self.path = _new_dir(earlier.parent, re.sub(r"(\.resume-\d+)+$", "", earlier.name) + ".resume")
        else:
            self.path = _new_dir(Path(root), name)
        self.meta = {
            "format": FORMAT, "name": self.path.name,
            "created": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
            "status": "running", "reason": None,
            "resumes": os.path.relpath(earlier, self.path) if earlier is not None else None,
            "devices": {"adc": f"{type(adc).__name__} on {adc.port}", "arm": type(arm).__name__,
                        "gripper": f"{type(gripper).__name__} on {getattr(gripper, 'port', '?')}"
                        if gripper is not None else None},
            "calibration": calibration.to_dict(), "steps": {}, "config": config or {},
        }
        if earlier_meta is not None:
            self._reuse(earlier, earlier_meta)
        self._save()

    def _save(self) -> None:
        _write_yaml_atomic(self.path / SESSION_FILE, self.meta)

    def _reuse(self, earlier: Path, meta: dict) -> None:
        steps = meta.get("steps", {})
        link = os.path.relpath(earlier, self.path)
        dry = steps.get("dry_run", {})
        if dry.get("status") in ("done", "reused"):
            source = earlier / os.path.normpath(dry.get("from", "."))
            table = np.genfromtxt(source / "dry-run.csv", delimiter=",", names=True)
            self.baseline = Baseline.from_dry_run(table["tau"], table["force"], dry["mode"])
            self.meta["steps"]["dry_run"] = {**dry, "status": "reused",
                                             "from": os.path.relpath(source, self.path)}
        dens = steps.get("density", {})
        if dens.get("status") in ("done", "reused"):
            self.density = DensityMeasurement(**dens["measurement"])
            self.meta["steps"]["density"] = {**dens, "status": "reused", "from": link}

    @contextlib.contextmanager
    def _step(self, name: str):
        step = self.meta["steps"][name] = {"status": "running"}
        self._save()
        try:
            yield step
        except BaseException as exc:
            status = "interrupted" if isinstance(exc, KeyboardInterrupt) else "failed"
            reason = f"{type(exc).__name__}: {exc}"
            step.update(status=status, reason=reason)
            self.meta.update(status=status, reason=f"{name}: {reason}")
            self._save()
            raise
        step["status"] = "done"
        self._save()

    def grip(self, force_percent: float = 50.0, *, timeout: float = 10.0) -> None:
        """Initialise the gripper, set the force [percent of the maximum] and close on the rod."""
        if self.gripper is None:
            raise ValueError("Session.grip: this session has no gripper")
        with self._step("grip") as step:
            self.gripper.initialise(timeout)
            self.gripper.set_force(force_percent)
            status = self.gripper.close_on_rod(timeout)
            step.update(force_percent=force_percent, position=status.position)

    def dry_run(self, trajectory: Trajectory, *, mode: str = "mean") -> Baseline:
        """Record the force without fluid along ``trajectory`` (the rod held still in air for ``mean``, the
        programme run in air for ``profile``) and keep it as the baseline."""
        if mode not in ("mean", "profile"):
            raise ValueError(f"dry run mode {mode!r}; expected 'mean' or 'profile'")
        with self._step("dry_run") as step, \
                _Log(self.path / "dry-run-adc.csv", ["t_device", "t_host", "raw"], self.flush_interval) as adc_log, \
                _Log(self.path / "dry-run-poses.csv", ["t_host", "x", "y", "z"], self.flush_interval) as pose_log, \
                _Log(self.path / "dry-run.csv", ["tau", "force"], self.flush_interval) as table:
            taus, forces = [], []

            def keep(sample: Sample, h: float, tau: float, pose) -> None:
                force = float(self.calibration.force(sample.counts))
                table.write(tau, force)
                taus.append(tau)
                forces.append(force)

            stats = self._acquire(trajectory, adc_log, pose_log, keep)
            self.baseline = Baseline.from_dry_run(taus, forces, mode)
            step.update(mode=mode, baseline=self.baseline.mean, std=self.baseline.std, **stats)
        return self.baseline

    def measure_density(self, rod_weight: float, immersed_reading: float, immersed_depth: float,
                        rod_cross_section: float | None = None) -> DensityMeasurement:
        """Record the Archimedes measurement: G [N] in air, R [N] immersed at rest, depth h [m], optional A [m²];
        rho = (G - R) / (A h g)."""
        with self._step("density") as step:
            area = rod_cross_section if rod_cross_section is not None else math.pi * self.rod.radius**2
            if not (rod_weight > immersed_reading and immersed_depth > 0 and area > 0):
                raise ValueError(f"density: need G > R and h, A > 0; got G = {rod_weight} N, "
                                 f"R = {immersed_reading} N, h = {immersed_depth} m, A = {area} m²")
            self.density = DensityMeasurement(rod_weight, immersed_reading, immersed_depth, rod_cross_section)
            step.update(measurement={"rod_weight": rod_weight, "immersed_reading": immersed_reading,
                                     "immersed_depth": immersed_depth, "rod_cross_section": rod_cross_section},
                        density=(rod_weight - immersed_reading) / (area * immersed_depth * GRAVITY))
        return self.density

    def stir(self, trajectory: Trajectory, name: str = "stir") -> Path:
        """Stir along ``trajectory``, writing the recording as samples arrive; returns its directory. ``name`` names
        the step, its files (``<name>-adc.csv``, ``<name>-poses.csv``) and the recording's directory, so that a
        session holds several stirs; a recording other than ``stir`` is labelled ``<session>-<name>``."""
        if name in self.meta["steps"] or not re.fullmatch(r"[a-z][a-z0-9-]*", name):
            raise ValueError(f"Session.stir: name {name!r} is taken or not a lower-case word (a-z, 0-9, -)")
        if trajectory.max_offset() + self.rod.radius >= self.cup.radius:
            raise ValueError(f"the trajectory takes the rod's axis {trajectory.max_offset():.4f} m off the cup's "
                             f"axis; with a rod of radius {self.rod.radius} m it would hit the wall at "
                             f"{self.cup.radius} m")
        if self.baseline is None:
            warnings.warn("stirring without a dry run: the force keeps the grip preload and sensor offset",
                          HardwareWarning, stacklevel=2)
        with self._step(name) as step, \
                _Log(self.path / f"{name}-adc.csv", ["t_device", "t_host", "raw"], self.flush_interval) as adc_log, \
                _Log(self.path / f"{name}-poses.csv", ["t_host", "x", "y", "z"], self.flush_interval) as pose_log:
            step["recording"] = name
            label = self.path.name if name == "stir" else f"{self.path.name}-{name}"
            writer = None
            origin = []
            saturated = 0

            def row(sample: Sample, h: float, tau: float, pose) -> None:
                nonlocal writer, saturated
                force = float(self.calibration.force(sample.counts))
                if self.baseline is not None:
                    force -= float(self.baseline(tau))
                if not math.isfinite(force):
                    saturated += 1
                    return
                if self.sensor.one_sided:
                    force = max(0.0, force)
                if writer is None:
                    writer = RecordingWriter(self.path / name, cup=self.cup, rod=self.rod, sensor=self.sensor,
                                             density=self.density, name=label, fluid=self.fluid,
                                             temperature=self.temperature, optional_columns=("z", "raw"),
                                             flush_interval=self.flush_interval)
                    origin.append(sample.t_device)
                writer.append(sample.t_device - origin[0], pose[0], pose[1], force, z=pose[2], raw=sample.counts)

            try:
                stats = self._acquire(trajectory, adc_log, pose_log, row, watch=self._check_grip)
            except BaseException as exc:
                if writer is not None:
                    writer.close(complete=False, reason=f"{type(exc).__name__}: {exc}")
                    step.update(rows=writer.rows_written)
                raise
            if writer is None:
                raise HardwareError(f"the stir produced no row: none of the {stats['samples']} samples of "
                                    f"{self.adc.name} on {self.adc.port} fell within the {stats['poses']} poses "
                                    f"of the {self.arm.name}; are both clocks monotonic?")
            writer.close()
            step.update(rows=writer.rows_written, saturated=saturated, **stats)
        return self.path / name

    def annotate(self, key: str, value) -> None:
        """Keep ``value`` (plain data) under ``key`` in session.yaml, e.g. the sequential mode's decisions."""
        self.meta[key] = value
        self._save()

    def _check_grip(self) -> None:
        if self.gripper is not None and self.gripper.status().grip is GripState.DROPPED:
            raise GripperError(f"{type(self.gripper).__name__} on {getattr(self.gripper, 'port', '?')}: the rod "
                               "was dropped during the stir (grip_state DROPPED)")

    def _acquire(self, trajectory: Trajectory, adc_log: _Log, pose_log: _Log,
                 on_sample: Callable[[Sample, float, float, tuple], None],
                 watch: Callable[[], None] | None = None) -> dict:
        """Run the arm along ``trajectory`` in a thread while reading the ADC here; hand every sample within the
        poses' span to ``on_sample(sample, host time [s], programme time [s], (x, y, z) [m])``."""
        poses = _Poses(pose_log)
        clock = ClockAligner(self.latency)
        pending: collections.deque[Sample] = collections.deque()
        stop, done, failure = threading.Event(), threading.Event(), []
        counts = {"samples": 0, "before_motion": 0}

        def drive() -> None:
            try:
                self.arm.follow(trajectory, poses.add, stop)
            except BaseException as exc:  # handed to the main thread
                failure.append(exc)
            finally:
                done.set()

        def emit() -> None:
            fit = clock.fit()
            while pending:
                h = float(fit.to_host(pending[0].t_device))
                pose = poses.at(h)
                if pose == "after":
                    return
                sample = pending.popleft()
                if pose == "before":
                    counts["before_motion"] += 1
                else:
                    on_sample(sample, h, h - poses.t[0], pose)

        def take(sample: Sample) -> None:
            adc_log.write(sample.t_device, sample.t_host, sample.counts)
            clock.add(sample.t_device, sample.t_host)
            pending.append(sample)
            counts["samples"] += 1

        arm = threading.Thread(target=drive, name="diffstir-arm", daemon=True)
        self.adc.start()
        try:
            take(self.adc.read())  # the sensor streams before the rod moves
            arm.start()
            last_watch = time.monotonic()
            while True:
                if failure:
                    raise failure[0]
                finished = done.is_set()
                take(self.adc.read())
                emit()
                if finished and pending:
                    break
                if watch is not None and time.monotonic() - last_watch >= self.flush_interval:
                    watch()
                    last_watch = time.monotonic()
        finally:
            stop.set()
            if arm.is_alive():
                arm.join(timeout=5.0)
            self.adc.stop()
            if pending:  # after a fault: keep what the poses so far can place; the fault itself propagates
                with contextlib.suppress(Exception):
                    emit()
        gap, start, median = poses.largest_gap()
        if gap > POSE_GAP_FACTOR * median:
            warnings.warn(f"the {self.arm.name} reported no pose for {gap:.3f} s from programme time {start:.3f} s "
                          f"(its median interval is {median * 1e3:.1f} ms); the rod's position there is a straight "
                          "chord between the poses either side", HardwareWarning, stacklevel=3)
        fit = clock.fit()
        return {**counts, "after_motion": len(pending), "poses": len(poses.t), "largest_pose_gap": gap,
                "skipped_lines": self.adc.skipped,
                "clock": {"offset": fit.offset, "rate": fit.rate, "latency": fit.latency}}

    def close(self) -> None:
        """Mark the session complete unless a step failed or was interrupted."""
        if self.meta["status"] == "running":
            self.meta["status"] = "complete"
            self._save()

    def __enter__(self) -> "Session":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc is not None and self.meta["status"] == "running":
            self.meta.update(status="interrupted" if isinstance(exc, KeyboardInterrupt) else "failed",
                             reason=f"{type(exc).__name__}: {exc}")
            self._save()
        self.close()
