"""Behaviour classification: one fluid stirred at several speeds is Newtonian, shear-thinning, shear-thickening or
yield-stress (the paper's Fig. 5 experiment), with a statistical test, a confidence, and the law that explains all
speeds at once. See docs/behaviour.md.
"""

from .classify import (CLASSES, Classification, JointYieldTest, Slope, SlopeEstimate, classify, combined_slope,
                       joint_yield_test, log_slope)
from .joint import JointFit, JointProblem, joint_fit
from .pipeline import Behaviour, characterise, reclassify
from .settings import JOINT_MODELS, SLOPE_TESTS, BehaviourSettings

__all__ = ["Behaviour", "BehaviourSettings", "CLASSES", "Classification", "JOINT_MODELS", "JointFit", "JointProblem",
           "JointYieldTest", "SLOPE_TESTS", "Slope", "SlopeEstimate", "characterise", "classify", "combined_slope",
           "joint_fit", "joint_yield_test", "log_slope", "reclassify"]
