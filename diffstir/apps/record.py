"""diffstir-record: a recording session on the rig (docs/hardware.md): grip, dry run, density, stir.

    diffstir-record hardware.adc.port=/dev/ttyACM0 hardware.gripper.port=/dev/ttyUSB0 \\
        hardware.arm.host=192.168.1.10 'hardware.arm.frame.origin=[0.4,0.0,0.25]' \\
        calibration=calib/rp-c18-0042.yaml fluid="castor oil" interactive=true
    diffstir-record hardware/adc=emulated hardware/arm=replay hardware/gripper=emulated \\
        density.rod_weight=0.5 density.immersed_reading=0.11 out=/tmp/runs stir.duration=3

Configs: conf/record.yaml and conf/hardware/{adc,arm,gripper}/. Exit status: 0 done, 1 a device's error, 2 a setting
refused, 130 / 143 interrupted (SIGINT / SIGTERM; everything recorded so far is kept, partial recordings marked
complete: false).
"""

from __future__ import annotations

import contextlib
import math
import sys
from dataclasses import asdict

import numpy as np
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from diffstir.apps import Run, command
from diffstir.errors import ConfigError, DiffstirError
from diffstir.hardware import DensitySettings, HardwareError, Session, StirSettings, load_calibration, load_trajectory
from diffstir.recording import CupGeometry, RodGeometry, SensorSpec
from diffstir.trajectory import Trajectory, circle

DENSITY_FIELDS = {"rod_weight": "N", "immersed_reading": "N", "immersed_depth": "m"}


def _programme(stir: StirSettings) -> Trajectory:
    """The stirring programme: a trajectory file, or a circle of ``radius`` [m] at ``speed`` [m/s] or
    ``rev_per_s`` [rev/s] (speed = 2 pi radius rev_per_s)."""
    if stir.file:
        return load_trajectory(stir.file)
    speed = stir.speed if stir.speed is not None else 2 * math.pi * stir.radius * stir.rev_per_s
    return circle(stir.radius, speed, stir.duration, ramp_time=stir.ramp_time, clockwise=stir.clockwise,
                  sample_rate=200.0)


def _dry_programme(stir: Trajectory, mode: str, duration: float, lift: float) -> Trajectory:
    """The dry run: held still at the programme's start (mean), or the programme itself (profile), lifted by
    ``lift`` [m] out of the fluid."""
    if mode == "profile":
        return Trajectory(stir.t, stir.xy, stir.z + lift, stir.angle)
    t = np.linspace(0.0, duration, max(2, int(duration * 100) + 1))
    return Trajectory(t, np.broadcast_to(stir.xy[0], (t.size, 2)), stir.z[0] + lift, 0.0)


def _density(settings: DensitySettings, depth: float, interactive: bool) -> dict | None:
    """The density measurement's values from the settings (h defaults to the rod's immersion ``depth`` [m]);
    missing ones are asked for later when interactive."""
    if settings.skip:
        return None
    values = {k: getattr(settings, k) for k in (*DENSITY_FIELDS, "rod_cross_section")}
    if values["immersed_depth"] is None:
        values["immersed_depth"] = depth
    missing = [k for k in DENSITY_FIELDS if values[k] is None]
    if missing and not interactive:
        raise ConfigError("density: " + ", ".join(f"density.{k} ({DENSITY_FIELDS[k]})" for k in missing)
                         + " not set; give them, or density.skip=true, or interactive=true to be asked")
    return values


def _ask_missing(values: dict) -> dict:
    for key, unit in DENSITY_FIELDS.items():
        while values[key] is None:
            text = input(f"{key.replace('_', ' ')} [{unit}]: ")
            with contextlib.suppress(ValueError):
                values[key] = float(text)
    return values


def record(cfg: DictConfig) -> Session:
    """Run the session ``cfg`` describes; returns it (its ``path`` holds everything recorded). The ``sensor``,
    ``grip``, ``dry_run``, ``density`` and ``stir`` blocks are built on their schemas (``diffstir.hardware.settings``,
    registered in ``diffstir.apps``): a value outside its range or choices is a ConfigError before any device
    opens."""
    sensor, grip, dry_run, density_settings, stir_settings = (
        OmegaConf.to_object(cfg[key]) for key in ("sensor", "grip", "dry_run", "density", "stir"))
    interactive = bool(cfg.interactive)
    density = _density(density_settings, cfg.rig.rod.immersion_depth, interactive)
    rig = instantiate(cfg.rig)
    if rig.rod.mesh is not None:
        raise ConfigError("rig.rod.mesh: a recording's rod is a cylinder; record with rig.rod.mesh=null")
    stir = _programme(stir_settings)
    dry = _dry_programme(stir, dry_run.mode, dry_run.duration, dry_run.lift)

    def step(message: str) -> None:
        if interactive:
            input(f"{message} [Enter: go on, Ctrl-C: stop] ")
        else:
            print(message, flush=True)

    with contextlib.ExitStack() as devices:
        adc = devices.enter_context(instantiate(cfg.hardware.adc))
        arm = devices.enter_context(instantiate(cfg.hardware.arm))
        gripper = (devices.enter_context(instantiate(cfg.hardware.gripper))
                   if cfg.hardware.gripper._target_ else None)
        calibration = load_calibration(cfg.calibration) if cfg.calibration else getattr(adc, "calibration", None)
        if calibration is None:
            raise ConfigError("no force calibration: set calibration=<file> (docs/hardware.md, 'Calibration')")
        session = Session(
            cfg.out, adc=adc, arm=arm, calibration=calibration, gripper=gripper, name=cfg.name, resume=cfg.resume,
            cup=CupGeometry(rig.cup.radius, fill_height=rig.cup.fill_height),
            rod=RodGeometry(rig.rod.radius, rig.rod.immersion_depth),
            sensor=SensorSpec(**{**asdict(sensor), "axis": tuple(sensor.axis) if sensor.axis else None}),
            fluid=cfg.fluid, temperature=cfg.temperature, flush_interval=cfg.flush_interval, latency=cfg.latency,
            config=OmegaConf.to_container(cfg, resolve=True))
        Run.writes(session.path)
        print(f"session {session.path}", flush=True)
        with session:
            if gripper is not None:
                step("Hold the rod between the gripper's fingers: the gripper initialises and closes on it.")
                session.grip(grip.force_percent, timeout=grip.timeout)
            if session.baseline is None:
                step(f"Dry run ({dry_run.mode}): the rod is held {dry_run.lift} m above its immersed pose, "
                     "out of the fluid.")
                session.dry_run(dry, mode=dry_run.mode)
            if session.density is None and density is not None:
                if interactive:
                    step("Density: weigh the rod held vertical in air (G), then immersed at rest (R).")
                session.measure_density(**_ask_missing(density))
            step("Stir: the cup must be in place; the rod goes to its immersed start pose and stirs.")
            session.stir(stir)
    return session


@command("diffstir-record", "record")
def main(cfg: DictConfig) -> None:
    """Console entry point ``diffstir-record``."""
    try:
        session = record(cfg)
    except DiffstirError:
        raise
    except (HardwareError, ValueError, OSError) as exc:
        print(f"diffstir-record: {exc}", file=sys.stderr)
        sys.exit(1)
    steps = session.meta["steps"]
    print(f"done: {session.path}: {steps['stir'].get('rows', 0)} rows, "
          f"{steps['stir'].get('skipped_lines', 0)} bad sensor lines skipped", flush=True)


if __name__ == "__main__":
    main()
