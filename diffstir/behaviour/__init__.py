"""Behaviour classification: one fluid stirred at several speeds is Newtonian, shear-thinning, shear-thickening or
yield-stress (the paper's Fig. 5 experiment), with a statistical test, a confidence, and the law that explains all
speeds at once. See docs/behaviour.md.
"""

from .apparent import ViscosityPoint, window_viscosity
from .classify import (CLASSES, Classification, JointYieldTest, Slope, SlopeEstimate, classify, combined_slope,
                       joint_yield_test, log_slope)
from .joint import JointFit, JointProblem, joint_fit
from .pipeline import JOINT_MODELS, SLOPE_TESTS, Behaviour, characterise, combined_density, reclassify
from .report import write_behaviour_report
from .windows import SpeedWindow, speed_windows

__all__ = ["CLASSES", "JOINT_MODELS", "SLOPE_TESTS", "Behaviour", "Classification", "JointFit", "JointProblem",
           "JointYieldTest", "Slope", "SlopeEstimate", "SpeedWindow", "ViscosityPoint", "characterise", "classify",
           "combined_density", "combined_slope", "joint_fit", "joint_yield_test", "log_slope", "reclassify",
           "speed_windows", "window_viscosity", "write_behaviour_report"]
