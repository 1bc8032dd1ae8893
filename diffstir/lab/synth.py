"""Synthesise a recording: simulate the truth, read it through a sensor model, measure the density, and keep the
truth in a separate file.

The truth is one of two simulations, chosen by the type of ``sim_config``:

* a ``SimConfig``: the fitting simulator (``StirringSimulator``) with the fluid's law, optionally wrapped in
  ``HiddenPhysics`` and with a slipping rod, at its own resolution (the lab's default is finer than the fitting
  default). A 2-D slice gives a force per unit length [N/m], which the lab turns into the force on the rod [N] as
  the fit does, F = F'_2D h C (h the immersion depth [m], C the slice correction, ``diffstir.slice_correction``).
* a ``FiniteElementTruth``: the stir in the 3-D cup by finite elements (``diffstir.lab.fe_truth``), which shares no
  code with the fitting simulator; generalized-Newtonian fluids on a circle only.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch

from diffstir.density import DEPTH_RESOLUTION
from diffstir.errors import ConfigError
from diffstir.lab.fe_truth import FiniteElementTruth, fe_stir_force
from diffstir.lab.fluid import Fluid
from diffstir.lab.sensor import SensorModel, quantise
from diffstir.mpm import SimConfig, StirringSimulator
from diffstir.mpm.hidden_physics import HiddenPhysics, TemperatureDrift, Thixotropy, Viscoelasticity
from diffstir.recording import (
    CupGeometry, DensityMeasurement, Recording, RecordingError, RodGeometry, load_recording, save_recording,
    validate_recording,
)
from diffstir.report_files import to_json, write_text_atomically
from diffstir.rig import Rig
from diffstir.slice_correction import trajectory_correction
from diffstir.trajectory import Trajectory

TRUTH_FORMAT = "diffstir-lab-truth/1"
ROD_DENSITY = 700.0  # kg/m³: a hardwood rod (the paper's rod is wooden)
DEPTH_PLACEMENT = 0.5e-3  # m: the robot holds the rod at the nominal depth ± this (uniform) for the density reading


@dataclass(frozen=True)
class HiddenPhysicsSpec:
    """Which hidden physics the truth simulation has: each model or None, and the rod's Navier slip length [m]."""

    thixotropy: Thixotropy | None = None
    viscoelasticity: Viscoelasticity | None = None
    temperature: TemperatureDrift | None = None
    slip_length: float = 0.0

    @classmethod
    def from_mapping(cls, cfg: Mapping | None) -> "HiddenPhysicsSpec":
        """From ``{thixotropy: {...} | null, viscoelasticity: ..., temperature: ..., wall_slip: {slip_length}}``."""
        cfg = dict(cfg or {})
        unknown = sorted(set(cfg) - {"thixotropy", "viscoelasticity", "temperature", "wall_slip"})
        if unknown:
            raise ValueError(f"physics: unknown field(s) {unknown}; expected thixotropy, viscoelasticity, "
                             f"temperature, wall_slip")

        def build(kind, key):
            return kind(**dict(cfg[key])) if cfg.get(key) else None

        slip = dict(cfg.get("wall_slip") or {})
        return cls(build(Thixotropy, "thixotropy"), build(Viscoelasticity, "viscoelasticity"),
                   build(TemperatureDrift, "temperature"), float(slip.get("slip_length", 0.0)))

    @property
    def in_material(self) -> bool:
        return any(m is not None for m in (self.thixotropy, self.viscoelasticity, self.temperature))

    def as_dict(self) -> dict:
        return {"thixotropy": None if self.thixotropy is None else asdict(self.thixotropy),
                "viscoelasticity": None if self.viscoelasticity is None else asdict(self.viscoelasticity),
                "temperature_drift": None if self.temperature is None else asdict(self.temperature),
                "wall_slip": {"slip_length": self.slip_length}}


@dataclass
class LabRecording:
    """A synthesised recording and its truth: ``recording`` (what the rig gives), ``truth`` (JSON-ready dict),
    and the true horizontal force ``true_force`` [N] (S, 2) at the simulation's ``sim_times`` [s] (S,)."""

    recording: Recording
    truth: dict
    sim_times: np.ndarray
    true_force: np.ndarray


def truth_path(recording_dir: str | Path) -> Path:
    """Where the truth of the recording ``recording_dir`` lives: ``<dir>.truth.json`` beside it."""
    path = Path(recording_dir)
    return path.with_name(path.name + ".truth.json")


def density_block(density: float, rig: Rig, sensor: SensorModel, rng: np.random.Generator) -> tuple[
        DensityMeasurement, dict]:
    """The Archimedes readings a real rig would give for a fluid of ``density`` [kg/m³], and their true values.

    G = ρ_rod π r² L g (a wooden rod of length L), R = G − ρ g π r² h with the rod held at the nominal immersion
    depth ± DEPTH_PLACEMENT (uniform); G and R are read through ``sensor.static_reading`` (gain, offset, averaged
    noise, quantisation), ``sensor.density_repeats`` times each (more than once: the lists of readings), h on a
    ruler with DEPTH_RESOLUTION (0.1 mm) steps.
    """
    area = math.pi * rig.rod.radius**2
    weight = ROD_DENSITY * area * rig.rod.length * rig.gravity
    depth = rig.rod.immersion_depth + rng.uniform(-DEPTH_PLACEMENT, DEPTH_PLACEMENT)
    immersed = weight - density * rig.gravity * area * depth
    measured_depth = float(quantise(np.array([depth]), DEPTH_RESOLUTION)[0])
    if sensor.density_repeats == 1:
        m = DensityMeasurement(rod_weight=sensor.static_reading(weight, rng),
                               immersed_reading=sensor.static_reading(immersed, rng), immersed_depth=measured_depth)
    else:
        g = [sensor.static_reading(weight, rng) for _ in range(sensor.density_repeats)]
        r = [sensor.static_reading(immersed, rng) for _ in range(sensor.density_repeats)]
        m = DensityMeasurement.of_readings(g, r, measured_depth)
    truth = {"rod_weight": weight, "immersed_reading": immersed, "immersed_depth": depth,
             "rod_density": ROD_DENSITY, "rod_length": rig.rod.length, "gravity": rig.gravity}
    return m, truth


@dataclass
class TruthSimulation:
    """A truth simulation before any sensor reads it: the horizontal force on the rod ``force`` [N] (S, 2) at
    ``times`` [s] (S,), and what made it (``discretisation``: particles and grid, or the finite elements' mesh).
    One truth simulation can be read by many sensor models."""

    fluid: Fluid
    trajectory: Trajectory
    rig: Rig
    sim_config: SimConfig | FiniteElementTruth
    physics: HiddenPhysicsSpec
    times: np.ndarray
    force: np.ndarray
    dt: float
    discretisation: dict
    per_unit_length: bool
    slice_factor: float = 1.0  # C applied to a 2-D truth's force (``diffstir.slice_correction``) [1]

    @classmethod
    def silent(cls, fluid: Fluid, trajectory: Trajectory, rig: Rig, times: np.ndarray,
               sim_config: SimConfig | None = None, physics: HiddenPhysicsSpec | None = None) -> "TruthSimulation":
        """A truth of zero force at ``times`` [s], simulated by nothing: what a sensor makes of ``trajectory``
        alone (its samples, their validation) before any simulation is spent on it."""
        return cls(fluid, trajectory, rig, sim_config or SimConfig(dim=2), physics or HiddenPhysicsSpec(), times,
                   np.zeros((times.size, 2)), float(times[1] - times[0]), {}, False)


def simulate_truth(fluid: Fluid, trajectory: Trajectory, *, rig: Rig | None = None,
                   sim_config: SimConfig | None = None, physics: HiddenPhysicsSpec | None = None, seed: int = 0,
                   cache_dir: str | Path | None = None) -> TruthSimulation:
    """Simulate ``fluid`` stirred along ``trajectory`` in ``rig`` with the truth ``sim_config`` (a ``SimConfig``
    or a ``FiniteElementTruth``) and hidden ``physics`` (``seed`` seeds torch)."""
    rig = rig or Rig()
    sim_config = sim_config or SimConfig(dim=2)
    physics = physics or HiddenPhysicsSpec()
    if isinstance(sim_config, FiniteElementTruth):
        if physics.in_material or physics.slip_length > 0:
            raise ConfigError("lab/physics: hidden physics needs an MPM truth (lab/sim=truth2d or truth3d); the 3-D "
                              "finite-element truth (lab/sim=fe3d) holds a generalized-Newtonian law only")
        stir = fe_stir_force(fluid, trajectory, rig, sim_config)
        return TruthSimulation(fluid, trajectory, rig, sim_config, physics, stir.times, stir.force, stir.dt,
                               stir.discretisation, per_unit_length=False)
    if physics.slip_length > 0:
        rig = replace(rig, rod=replace(rig.rod, slip_length=physics.slip_length))
    law = fluid.make_law()
    material = law
    if physics.in_material:
        material = HiddenPhysics(law, thixotropy=physics.thixotropy, viscoelasticity=physics.viscoelasticity,
                                 temperature=physics.temperature, horizon=trajectory.duration)
    torch.manual_seed(seed)
    simulator = StirringSimulator(material, rig, sim_config, density=fluid.density, cache_dir=cache_dir)
    with torch.no_grad():
        result = simulator(trajectory)
    times = trajectory.t[0] + result.dt * (np.arange(result.times.numel()) + 0.5)  # mid-step, float64
    factor, length = 1.0, 1.0  # 3-D: newtons
    if result.per_unit_length:  # 2-D: F = F' h C
        factor = trajectory_correction(rig, material, fluid.density, trajectory, times).factor
        length = rig.rod.immersion_depth * factor
    force = result.force.double().cpu().numpy()[:, :2] * length
    discretisation = {"method": f"MLS-MPM, {sim_config.dim}-D (diffstir.mpm)",
                      "particles": int(result.state.num_particles), "grid": list(simulator.scene.grid.shape)}
    return TruthSimulation(fluid, trajectory, rig, sim_config, physics, times, force, result.dt, discretisation,
                           bool(result.per_unit_length), factor)


def read_truth(truth_sim: TruthSimulation, sensor: SensorModel | None = None, *, seed: int = 0,
               name: str | None = None, label: str | None = None, programme: Mapping | None = None) -> LabRecording:
    """Read a truth simulation through ``sensor`` with random numbers from ``seed`` and synthesise the density
    readings. ``label`` is written to the recording's ``fluid`` field (default none: the recording does not name
    the fluid); ``programme`` (the programme's settings) is only recorded in the truth."""
    sensor = sensor or SensorModel()
    fluid, rig, sim_config, times = truth_sim.fluid, truth_sim.rig, truth_sim.sim_config, truth_sim.times
    rng = np.random.default_rng(seed)
    velocity = np.gradient(truth_sim.trajectory.poses(times)[0], times, axis=0)
    # from the programme's start, as a real recording starts before the arm moves (the first samples, before the
    # first mid-step force, read that force); a recording that began in motion would replay from rest
    t = sensor.sample_times(float(truth_sim.trajectory.t[0]), float(times[-1]))
    reading = sensor.read(times, truth_sim.force, velocity, t, rng)
    density, density_truth = density_block(fluid.density, rig, sensor, rng)
    xy = sensor.positions(truth_sim.trajectory.poses(t)[0], rng)  # drawn after the density readings
    rec = Recording(cup=CupGeometry(radius=rig.cup.radius, fill_height=rig.cup.fill_height),
                    rod=RodGeometry(radius=rig.rod.radius, immersion_depth=rig.rod.immersion_depth),
                    sensor=sensor.spec(), density=density, t=t + sensor.time_origin, x=xy[:, 0], y=xy[:, 1],
                    force=reading, name=name, fluid=label, temperature=fluid.temperature)
    validate_recording(rec)
    truth = {
        "format": TRUTH_FORMAT,
        "recording": name,
        "fluid": {"name": fluid.name, "density": fluid.density, "temperature": fluid.temperature,
                  "law": fluid.law, "law_parameters": fluid.make_law().parameters_si(), "source": fluid.source,
                  "notes": fluid.notes},
        "hidden_physics": truth_sim.physics.as_dict(),
        "sensor": sensor.as_dict(),
        "density_measurement": density_truth,
        "programme": dict(programme) if programme is not None else None,
        "rig": asdict(rig),
        "simulator": {"kind": "fe3d" if isinstance(sim_config, FiniteElementTruth) else f"mpm{sim_config.dim}d",
                      "config": asdict(sim_config), "dt": truth_sim.dt, "steps": int(times.size),
                      **truth_sim.discretisation,
                      "force_scale": ("2-D force per unit length times the rod's immersion depth [m] and the "
                                      "slice correction C (diffstir.slice_correction)"
                                      if truth_sim.per_unit_length else "3-D force"),
                      "slice_factor": truth_sim.slice_factor},
        "seed": seed,
        "units": "SI: m, s, N, kg/m^3, Pa, Pa s, K/s, 1/K; temperature in degC",
    }
    return LabRecording(rec, truth, times, truth_sim.force)


def check_programme(fluid: Fluid, trajectory: Trajectory, rig: Rig | None = None,
                    sensor: SensorModel | None = None) -> None:
    """Raise ConfigError, before any simulation, when the recording ``sensor`` would make of ``trajectory`` is
    invalid (too short for one stirring period, too sparse): the recording of a silent truth, validated."""
    try:
        read_truth(TruthSimulation.silent(fluid, trajectory, rig or Rig(), trajectory.t), sensor, name="programme")
    except RecordingError as error:
        problem = re.sub(r"^<unsaved recording 'programme'> \S+: ", "", str(error))
        raise ConfigError(f"lab/programme, lab/sensor: the recording they make would be invalid: {problem}") from None


def synthesise(fluid: Fluid, trajectory: Trajectory, *, rig: Rig | None = None, sim_config: SimConfig | None = None,
               sensor: SensorModel | None = None, physics: HiddenPhysicsSpec | None = None, seed: int = 0,
               name: str | None = None, label: str | None = None, programme: Mapping | None = None,
               cache_dir: str | Path | None = None) -> LabRecording:
    """Simulate the truth (``simulate_truth``) and read it through ``sensor`` (``read_truth``) with random numbers
    from ``seed``; a programme whose recording would be invalid is refused first (``check_programme``)."""
    check_programme(fluid, trajectory, rig, sensor)
    truth_sim = simulate_truth(fluid, trajectory, rig=rig, sim_config=sim_config, physics=physics, seed=seed,
                               cache_dir=cache_dir)
    return read_truth(truth_sim, sensor, seed=seed, name=name, label=label, programme=programme)


def write_lab_recording(lab: LabRecording, path: str | Path, *, overwrite: bool = False) -> tuple[Path, Path]:
    """Save the recording as the directory ``path`` and its truth as ``<path>.truth.json`` beside it (never
    inside); the recording is read back and validated. Returns (recording dir, truth file)."""
    path = Path(path)
    truth_file = truth_path(path)
    if truth_file.exists() and not overwrite:
        raise FileExistsError(f"{truth_file}: already exists; pass overwrite=True to replace it")
    save_recording(lab.recording, path, overwrite=overwrite)
    load_recording(path)
    write_text_atomically(truth_file, to_json(lab.truth))
    return path, truth_file


