"""Simulation problems shared by the tests: small rigs and closed-form references."""

from __future__ import annotations

import math
from pathlib import Path

import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf

from diffstir.mpm import SimConfig
from diffstir.rig import Rig

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
