"""The virtual lab: realistic stirring recordings with a known truth, kept apart from the recording.

``synthesise`` simulates a fluid (``Fluid``: any rheology law or a tabulated flow curve, and a density) stirred
along a programme (``stirring_programme``) in the rig, with optional hidden physics (``HiddenPhysics``:
thixotropy, viscoelasticity, temperature drift; a slipping rod), or by finite elements in the 3-D cup
(``FiniteElementTruth``, ``diffstir.lab.fe_truth``), reads the force through a sensor model
(``SensorModel``) and synthesises the Archimedes density readings; ``write_lab_recording`` saves the recording in
the project's format and the truth to ``<recording>.truth.json`` beside it. ``synthesise_blend`` stirs two fluids
together (``Blend``; docs/mixing.md). See docs/virtual-lab.md.
"""

from diffstir.lab.blend import Blend, BlendMaterial, simulate_blend, synthesise_blend
from diffstir.lab.fe_truth import FiniteElementTruth
from diffstir.lab.fluid import Fluid, make_fluid_law
from diffstir.lab.programme import Segment, programme_path, programme_speed, stirring_programme
from diffstir.lab.sensor import SensorModel, dead_band, first_order_lag, one_sided, quantise
from diffstir.lab.synth import (
    HiddenPhysicsSpec, LabRecording, TruthSimulation, density_block, read_truth, simulate_truth, synthesise,
    truth_path, write_lab_recording,
)

__all__ = [
    "Blend",
    "BlendMaterial",
    "FiniteElementTruth",
    "Fluid",
    "HiddenPhysicsSpec",
    "LabRecording",
    "Segment",
    "SensorModel",
    "TruthSimulation",
    "dead_band",
    "density_block",
    "first_order_lag",
    "make_fluid_law",
    "one_sided",
    "programme_path",
    "programme_speed",
    "quantise",
    "read_truth",
    "simulate_blend",
    "simulate_truth",
    "stirring_programme",
    "synthesise",
    "synthesise_blend",
    "truth_path",
    "write_lab_recording",
]
