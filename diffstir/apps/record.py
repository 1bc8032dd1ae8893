"""diffstir-record: a recording session on the rig (docs/hardware.md): grip, dry run, density, stir.

    diffstir-record hardware.adc.port=/dev/ttyACM0 hardware.gripper.port=/dev/ttyUSB0 \\
        hardware.arm.host=192.168.1.10 'hardware.arm.frame.origin=[0.4,0.0,0.25]' \\
        calibration=calib/rp-c18-0042.yaml fluid="castor oil" interactive=true
    diffstir-record hardware/adc=emulated hardware/arm=replay hardware/gripper=emulated \\
        density.rod_weight=0.5 density.immersed_reading=0.11 out=/tmp/runs stir.duration=3
    diffstir-record sequential.enabled=true calibration=calib/rp-c18-0042.yaml ...   # stir until decided

With ``sequential.enabled``, the sequential mode (docs/planning.md): the first stir at ``sequential.first``, then
after each stir the flow-curve analysis of every stir so far (``analysis-<k>/``, as ``diffstir-fit
experiment=flow_curve`` writes it, with ``next.json`` as ``diffstir-plan after=`` writes it) and the next stir it
calls for (``stir-<k+1>/``), until the fluid's family is decided or ``plan.budget`` is spent; the rod rests while
each analysis runs. session.yaml's ``sequence`` lists each step's stir and decision.

Configs: conf/record.yaml and conf/hardware/{adc,arm,gripper}/. Exit status: 0 done, 1 a device's error, 2 a setting
refused (or, in the sequential mode, an analysis that resolves no viscosity), 130 / 143 interrupted (SIGINT /
SIGTERM; everything recorded so far is kept, partial recordings marked complete: false).
"""

from __future__ import annotations

import contextlib
import json
import math
import sys
from dataclasses import asdict, replace
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from diffstir.apps import Run, check_processes, command, config_workers
from diffstir.apps.plan import CalibrationProgress, plan_inputs
from diffstir.behaviour import BehaviourSettings, characterise
from diffstir.errors import ConfigError, DiffstirError, is_number
from diffstir.hardware import DensitySettings, HardwareError, Session, StirSettings, load_calibration, load_trajectory
from diffstir.lab import programme_path
from diffstir.planning import rig_calibration
from diffstir.planning.result import PATH_RATE
from diffstir.planning.sequential import NextSegment, StirSoFar, first_stir, next_segment
from diffstir.recording import CupGeometry, RodGeometry, SensorSpec, load_recording
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


def stir_sequentially(session: Session, first: dict, analyse: Callable[[list[Path], Path], StirSoFar],
                      next_stir: Callable[[StirSoFar, float], NextSegment]) -> list[dict]:
    """Stir ``first`` (a programme mapping), then, after each stir k, ``analyse`` every stir so far into
    ``analysis-<k>/`` and stir the programme that ``next_stir`` calls for with the sensor's noise the dry run measured
    [N], until it calls for none (the family is decided, or no stir fits the budget left). Each stir starts where the
    last one left the rod, so that the arm does not drag it through the resting fluid to a start pose. Each step (its
    stir, the stir so far, the decision) goes into session.yaml's ``sequence`` as it is taken; returns the steps."""
    programme, recordings, steps = first, [], []
    while programme is not None:
        name = f"stir-{len(recordings) + 1}"
        path = programme_path(programme, PATH_RATE)  # as diffstir-plan's stir_path.csv
        recordings.append(session.stir(path, name=name))
        out = session.path / f"analysis-{len(recordings)}"
        so_far = analyse(recordings, out)
        step = next_stir(so_far, session.baseline.std)
        decision = json.loads(json.dumps({**step.to_dict(), "elapsed": so_far.elapsed}, default=float))
        (out / "next.json").write_text(json.dumps(decision, indent=2) + "\n")
        steps.append({"stir": name, "programme": programme, "analysis": out.name, **decision})
        session.annotate("sequence", steps)
        state = f"decided: {step.family}" if step.decided else f"so far {step.family or 'no family'}"
        then = ("" if step.decided else f"; next {step.speed:g} m/s for {step.duration:.3g} s"
                if step.speed is not None else "; no stir fits the budget left")
        speeds = ", ".join(f"{segment['speed']:g}" for segment in programme["segments"])
        print(f"{name}: {speeds} m/s; after {so_far.elapsed:.3g} s {state} (confidence {step.confidence:.3g})"
              f"{then}", flush=True)
        end = math.atan2(path.xy[-1, 1], path.xy[-1, 0])
        programme = None if step.speed is None else {**step.programme(programme["radius"]), "start_angle": end}
    return steps


def sequential_planner(cfg: DictConfig) -> tuple[dict, Callable, Callable]:
    """The sequential mode's first stir, its analysis and its next stir (``stir_sequentially``), from ``cfg``'s
    ``sim``, ``prior``, ``plan`` and ``sequential`` blocks, checked (and the rig calibrated) before any device
    opens. The next stir is planned for the session's sensor: ``plan.resolution`` and ``plan.sample_rate`` are the
    ``sensor`` block's (conf/record.yaml) and the noise is the dry run's."""
    check_processes(cfg)
    torch.set_num_threads(int(cfg.threads))
    if cfg.stir.file:
        raise ConfigError("stir.file: the sequential mode plans its own stirs; give stir.file=null or "
                          "sequential.enabled=false")
    if cfg.dry_run.mode == "profile":
        raise ConfigError("dry_run.mode = 'profile' runs one programme in air, and the sequential mode's stirs are "
                          "planned as it goes; use dry_run.mode=mean")
    if cfg.sensor.resolution is None:
        raise ConfigError("sensor.resolution = None; the sequential mode plans each stir for the sensor's "
                          "resolution: give it in N")
    rig, sim_config, prior, settings = plan_inputs(cfg)
    speeds = tuple(cfg.sequential.first)
    if len(speeds) < 2 or not all(is_number(u) and 0 < u <= settings.arm.max_speed for u in speeds):
        raise ConfigError(f"sequential.first = {list(speeds)} m/s; expected two or more speeds in (0, "
                          f"{settings.arm.max_speed}] m/s (plan.arm.max_speed)")
    workers = config_workers(cfg)
    with CalibrationProgress() as progress:
        calibration = rig_calibration(rig, prior, settings, sim_config, workers=workers, cache_dir=cfg.cache_dir,
                                      report=progress)

    def analyse(recordings: list[Path], out: Path) -> StirSoFar:
        result = characterise([load_recording(r) for r in recordings], config=sim_config,
                              settings=BehaviourSettings(analysis="flow_curve"), density=settings.density,
                              workers=workers, progress=True)
        result.write(out)
        so_far = StirSoFar.from_report(result.summary())
        if not so_far.speeds:
            raise DiffstirError(f"{out / 'report.json'}: no window of the stirs so far resolved a viscosity "
                                "(docs/flow-curve.md); the sequential mode has nothing to plan from")
        return so_far

    def next_stir(so_far: StirSoFar, noise: float) -> NextSegment:
        return next_segment(so_far, calibration, prior, replace(settings, noise=noise))

    return first_stir(settings, speeds), analyse, next_stir


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
    sequential = sequential_planner(cfg) if cfg.sequential.enabled else None
    stir = _programme(stir_settings) if sequential is None else programme_path(sequential[0], PATH_RATE)
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
            if sequential is None:
                session.stir(stir)
            else:
                stir_sequentially(session, *sequential)
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
    stirs = [name for name in steps if name == "stir" or name.startswith("stir-")]
    print(f"done: {session.path}: {len(stirs)} stir{'s' if len(stirs) > 1 else ''}, "
          f"{sum(steps[s].get('rows', 0) for s in stirs)} rows, "
          f"{sum(steps[s].get('skipped_lines', 0) for s in stirs)} bad sensor lines skipped", flush=True)


if __name__ == "__main__":
    main()
