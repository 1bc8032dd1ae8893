"""Identify a fluid from a stirring recording: fit each law through the simulator, quantify, select, report."""

from .models import FitModel
from .optimise import FitResult, fit_model
from .pipeline import DEFAULT_MODELS, Identification, identify
from .problem import FitProblem, StirProblem, Windows, rig_from_recording, trajectory_from_recording

__all__ = ["DEFAULT_MODELS", "FitModel", "FitProblem", "FitResult", "Identification", "StirProblem", "Windows",
           "fit_model", "identify", "rig_from_recording", "trajectory_from_recording"]
