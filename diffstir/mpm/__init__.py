"""Differentiable MLS-MPM simulation of a rod stirring a fluid in a cup."""

from .config import COARSE_STAGE, FINE_STAGE, SimConfig
from .hidden_physics import HiddenPhysics, TemperatureDrift, Thixotropy, Viscoelasticity
from .materials import Corotated, KelvinVoigt
from .sensitivity import Sensitivities, force_sensitivities
from .simulator import SimResult, StirringSimulator, simulate
from .state import State

__all__ = ["COARSE_STAGE", "Corotated", "FINE_STAGE", "HiddenPhysics", "KelvinVoigt", "Sensitivities", "SimConfig",
           "SimResult", "State", "StirringSimulator", "TemperatureDrift", "Thixotropy", "Viscoelasticity",
           "force_sensitivities", "simulate"]
