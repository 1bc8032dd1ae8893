"""Differentiable MLS-MPM simulation of a rod stirring a fluid in a cup."""

from .build import cache_root
from .config import COARSE_STAGE, FINE_STAGE, SimConfig
from .hidden_physics import HiddenPhysics, TemperatureDrift, Thixotropy, Viscoelasticity
from .materials import Corotated, KelvinVoigt, Material, StatefulMaterial, StepDependentMaterial, as_material
from .sensitivity import Sensitivities, force_sensitivities
from .simulator import SimResult, StirringSimulator, simulate
from .state import State

__all__ = ["COARSE_STAGE", "Corotated", "FINE_STAGE", "HiddenPhysics", "KelvinVoigt", "Material", "Sensitivities",
           "SimConfig", "SimResult", "State", "StatefulMaterial", "StepDependentMaterial", "StirringSimulator",
           "TemperatureDrift", "Thixotropy", "Viscoelasticity", "as_material", "cache_root", "force_sensitivities",
           "simulate"]
