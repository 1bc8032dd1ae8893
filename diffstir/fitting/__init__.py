"""The fitting engine: a law's parameters fitted through the simulator to a recording's force, with their
uncertainty and the selection among laws.

A fit problem (``FitProblem``: ``StirProblem`` for one recording) gives simulated sensor readings [N] for a model's
parameters θ (``FitModel``: a law's parameters in log or bounded coordinates, ``params_si`` their SI values);
``fit_model`` minimises the windowed residual, ``laplace`` turns its Jacobian into a covariance and 95 % intervals
(``Uncertainty``), ``select`` ranks laws by BIC, and ``Identification`` holds every law's fit of one recording. The
apparent viscosity of one speed window (``window_viscosity``) is the single-parameter fit that the behaviour and
mixing analyses repeat over windows. See docs/identification.md.
"""

from .apparent import ViscosityPoint, WindowsJob, window_event, window_simulations, window_viscosity
from .family import law_family
from .flow_points import PointsFit, fit_points, profiled
from .initial import (LADDER_VISCOSITIES, PROBE_INDEX_STEP, SHEAR_RATE_PROBES, YIELD_SHARES, ViscosityLadder,
                      characteristic_shear_rate, effective_shear_rate, initial_model, initial_models,
                      mean_stirring_speed, metzner_otto_constant, newtonian_embedding)
from .jobs import FitJob, MagnitudeJob, ReadingJob, mean_readings_on
from .magnitude import MAGNITUDE_STEPS
from .models import FitModel
from .nuisance import DEFAULT_NUISANCES, NO_NUISANCE, NUISANCES, UNITS, SensorNuisance, lag_response
from .optimise import OPTIMIZERS, FitResult, Readings, fit_model, noise_scale
from .parameters import MaterialParameters, ParameterSet, ThetaParameters, theta_of, value_of
from .problem import FitProblem, StirProblem, Windows, rig_from_recording, trajectory_from_recording
from .programme import PROGRAMME_SIMULATIONS, THICKEST_RUNG, ProgrammeFit, programme_viscosities
from .progress import Progress, fit_simulations
from .result import Identification, parameter_summary, parameter_uncertainty
from .selection import CRITERIA, bic, bic_of_rss, rank, schwarz_weights, select
from .settings import FitSettings
from .uncertainty import (COARSE_FORCE_ERROR, INERTIAL_FORCE_ERROR, MODEL_FORCE_ERROR, Z95, Uncertainty,
                          checked_model_error, effective_samples, force_error, identifiable_half_width, laplace,
                          log_viscosity_interval)
from .windows import PAUSE_SPEED, SpeedWindow, speed_windows

__all__ = ["COARSE_FORCE_ERROR", "CRITERIA", "DEFAULT_NUISANCES", "FitJob", "FitModel", "FitProblem", "FitResult",
           "FitSettings", "INERTIAL_FORCE_ERROR", "Identification", "LADDER_VISCOSITIES", "MAGNITUDE_STEPS",
           "MODEL_FORCE_ERROR", "MagnitudeJob", "MaterialParameters", "NO_NUISANCE", "NUISANCES", "OPTIMIZERS",
           "PAUSE_SPEED", "PROBE_INDEX_STEP", "PROGRAMME_SIMULATIONS", "ParameterSet", "PointsFit", "ProgrammeFit",
           "Progress", "ReadingJob", "Readings", "SHEAR_RATE_PROBES", "SensorNuisance", "SpeedWindow", "StirProblem",
           "THICKEST_RUNG", "ThetaParameters", "UNITS", "Uncertainty", "ViscosityLadder", "ViscosityPoint", "Windows",
           "WindowsJob", "YIELD_SHARES", "Z95", "bic", "bic_of_rss", "characteristic_shear_rate", "checked_model_error",
           "effective_samples", "effective_shear_rate", "fit_model", "fit_points", "fit_simulations", "force_error",
           "identifiable_half_width", "initial_model", "initial_models", "lag_response", "laplace", "law_family",
           "log_viscosity_interval", "mean_readings_on", "mean_stirring_speed", "metzner_otto_constant",
           "newtonian_embedding", "noise_scale", "parameter_summary", "parameter_uncertainty", "profiled",
           "programme_viscosities", "rank", "rig_from_recording", "schwarz_weights", "select", "speed_windows",
           "theta_of", "trajectory_from_recording", "value_of", "window_event", "window_simulations",
           "window_viscosity"]
