"""Simulation problems shared by the tests: small rigs and closed-form references."""

from __future__ import annotations

import math
from pathlib import Path

import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf

from diffstir.mpm import SimConfig, StirringSimulator
from diffstir.mpm.state import State
from diffstir.rheology import Newtonian
from diffstir.rig import Rig, Rod
from diffstir.trajectory import stationary

DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])

PAPER_RIG = Rig()


def fitting_default() -> SimConfig:
    """The simulation the fit ends on (`conf/sim/slice2d.yaml`): the closed-form checks hold it to its word."""
    return instantiate(OmegaConf.load(Path(__file__).resolve().parents[1] / "conf/sim/slice2d.yaml"))


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
