"""Simulation problems shared by the tests: small rigs and closed-form references."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf

from diffstir.fitting.problem import rig_from_recording, trajectory_from_recording
from diffstir.mpm import SimConfig, StirringSimulator
from diffstir.mpm.state import State
from diffstir.recording import Recording
from diffstir.rheology import Newtonian
from diffstir.rig import Rig, Rod
from diffstir.slice_correction import trajectory_correction
from diffstir.trajectory import stationary

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])

PAPER_RIG = Rig()


def fitting_default() -> SimConfig:
    """The simulation the fit ends on (`conf/sim/slice2d.yaml`): the closed-form checks hold it to its word."""
    return instantiate(OmegaConf.load(Path(__file__).resolve().parents[1] / "conf/sim/slice2d.yaml"))


def fitted_force(law, blank: Recording, config: SimConfig, density: float = 1000.0) -> tuple[np.ndarray, np.ndarray]:
    """What the fit reads as the force of ``law`` on ``blank``'s rig and rod path: the step times [s] and the force
    [N] (steps, 3) of the fitting simulator along the spline the fitter replays, a 2-D slice's force per length
    times the immersion h and the slice correction C (``fitting.problem``: F = F' h C)."""
    rig, trajectory = rig_from_recording(blank), trajectory_from_recording(blank)
    with torch.no_grad():
        result = StirringSimulator(law, rig, config, density=density)(trajectory)
    scale = 1.0
    if config.dim == 2:
        scale = blank.rod.immersion_depth * trajectory_correction(rig, law, density, trajectory, blank.t).factor
    return result.times.double().numpy(), result.force.double().numpy() * scale


def couette_torque_newtonian(mu: float, omega: float, a: float, b: float, length: float = 1.0) -> float:
    """Torque [N·m] on a rod of radius a spinning at omega [rad/s] inside a still cylinder of radius b:
    M = 4π μ L Ω a² b² / (b² − a²)."""
    return 4 * math.pi * mu * length * omega * a**2 * b**2 / (b**2 - a**2)


def couette_torque_power_law(k: float, n: float, omega: float, a: float, b: float, length: float = 1.0) -> float:
    """Power-law fluid (K, n): M = 2π L K a² [2Ω / (n (1 − (a/b)^(2/n)))]^n."""
    return 2 * math.pi * length * k * a**2 * (2 * omega / (n * (1 - (a / b) ** (2 / n)))) ** n


def translating_rod_force(mu: float, speed: float, a: float, b: float) -> float:
    """Exact 2-D Stokes drag per unit length [N/m] on a rod at the centre of a cylinder:
    F' = 4π μ U / [ln(b/a) − (b² − a²)/(b² + a²)]."""
    return 4 * math.pi * mu * speed / (math.log(b / a) - (b**2 - a**2) / (b**2 + a**2))


def numerical_viscosity(config: SimConfig, cache_dir: str | Path | None, duration: float = 0.2, cells: int = 8,
                        amplitude: float = 0.01) -> float:
    """ν [m²/s] at which an inviscid shear wave u_x = A sin(k y) (wavelength ``cells`` cells, in a Gaussian envelope
    of 2 cm in the middle of the cup) decays by the transfers alone: A(t) = A(0) exp(−ν k² t)."""
    sim = StirringSimulator(Newtonian(eta=1e-4), Rig(rod=Rod(radius=0.003)), config, density=1000.0,
                            cache_dir=cache_dir)
    trajectory = stationary(duration, position=(0.03, 0.0))
    state = sim.initial_state(trajectory)
    k = 2 * math.pi / (cells * config.dx)

    def envelope(x):
        return torch.exp(-(x.norm(dim=1) / 0.02) ** 2)

    def projection(s):  # the wave's amplitude by least squares on the particles
        shape = torch.sin(k * s.x[:, 1]) * envelope(s.x)
        return float((s.v[:, 0] * shape).sum() / (shape**2).sum())

    v, C = torch.zeros_like(state.v), torch.zeros_like(state.C)
    v[:, 0] = amplitude * torch.sin(k * state.x[:, 1]) * envelope(state.x)
    C[:, 0, 1] = amplitude * k * torch.cos(k * state.x[:, 1]) * envelope(state.x)
    start = State(x=state.x, v=v, C=C, J=state.J)
    with torch.no_grad():
        end = sim(trajectory, initial=start).state
    return -math.log(projection(end) / projection(start)) / (k**2 * duration)


def rod_in_pressure_gradient(config: SimConfig, g: float = 1.0) -> torch.Tensor:
    """The steady force per unit length [N/m], (2,), on the rod held still 15 mm off centre in the 2-D slice under a
    body force g [m/s²] along x (standing in for gravity, which a horizontal slice lacks): the closed form is the
    hydrostatic gradient's push, −ρ g π a² along x. 1 Pa·s damps the settling's sloshing; c = 2 m/s; the mean of
    the last 30 % of 0.6 s."""
    sim = StirringSimulator(Newtonian(eta=1.0), PAPER_RIG, config.replace(compressibility=None, sound_speed=2.0),
                            density=1000.0)
    sim.scene = replace(sim.scene, gravity=torch.tensor([g, 0.0], dtype=sim.scene.gravity.dtype,
                                                        device=sim.scene.gravity.device))
    with torch.no_grad():
        force = sim(stationary(0.6, position=(0.015, 0.0), sample_rate=1000.0)).force
    return force[int(0.7 * len(force)):].mean(0)
