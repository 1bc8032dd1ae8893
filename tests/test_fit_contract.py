"""The contract of every problem the fitter accepts (``fitting.FitProblem``): each implementation has its members
with the protocol's signatures, and a fit runs through each, the diagnosis's cached replay with a sound speed that
follows the stir (``SimConfig.compressibility``, the diagnosis's default ``sim: coarse2d``) included."""

import inspect
import math
from dataclasses import replace

import numpy as np
import pytest
import yaml

from diffstir.apps import CONF_DIR
from diffstir.behaviour.joint import JointProblem
from diffstir.diagnosis.candidates import PHYSICS_CANDIDATES, CachedReplay, Context, PhysicsModel
from diffstir.fitting.models import FitModel
from diffstir.fitting.optimise import fit_model
from diffstir.fitting.problem import FitProblem, StirProblem, Windows
from diffstir.fitting.windows import SpeedWindow
from diffstir.recording import CupGeometry, Recording, RodGeometry, SensorSpec
from diffstir.rheology import Newtonian
from diffstir.trajectory import circle

#: The rod is 2.5 cells across: coarse, but the same model; the sound speed follows the stir as in coarse2d.
FOLLOWING = {"dim": 2, "dx": 0.01, "sound_speed": 0.5, "compressibility": 0.03}


def recording(duration=0.3, force=0.02):
    """A short circular stir read tangentially; its stand-in reading [N] rises to ``force`` [N] as the rod starts."""
    traj = circle(radius=0.015, speed=0.06, duration=duration, ramp_time=0.05, sample_rate=100)
    return Recording(cup=CupGeometry(radius=0.0425, fill_height=0.13),
                     rod=RodGeometry(radius=0.0125, immersion_depth=0.08),
                     sensor=SensorSpec(mode="tangential", resolution=0.001, sample_rate=100.0), density=None,
                     t=traj.t, x=traj.xy[:, 0], y=traj.xy[:, 1], force=force * np.minimum(traj.t / 0.05, 1.0),
                     name="contract")


def implementations():
    from diffstir.mpm import SimConfig

    config = SimConfig(**FOLLOWING)
    rec = recording()
    stir = StirProblem(rec, config, 1000.0, Windows.of(rec, None, 0.0))
    joint = JointProblem([SpeedWindow(rec, 0.05, 0.15, 0.06), SpeedWindow(rec, 0.15, 0.3, 0.06)], config, 1000.0)
    ctx = Context(times=stir.times, measured=stir.measured, base_reading=stir.measured, scale_column=stir.measured,
                  accel_reading=None, noise=1e-3, shear_rate=4.8, duration=0.3, rebuild_time=1.0,
                  law=Newtonian(eta=0.8), rod_radius=0.0125)
    replay = CachedReplay(stir, PhysicsModel(PHYSICS_CANDIDATES["wall_slip"], ctx.law, ctx))
    return {"StirProblem": stir, "JointProblem": joint, "CachedReplay": replay}


def protocol_methods():
    return {name: value for name, value in vars(FitProblem).items()
            if callable(value) and not name.startswith("_")}


def test_the_protocol_names_what_the_fitter_reads():
    assert set(protocol_methods()) == {"loss", "simulate", "frozen"}
    assert {"config", "density", "recording", "times", "measured", "train", "weights"} <= set(
        FitProblem.__annotations__)


@pytest.mark.parametrize("name", ["StirProblem", "JointProblem", "CachedReplay"])
def test_every_problem_satisfies_the_protocol(name):
    problem = implementations()[name]
    assert isinstance(problem, FitProblem)
    for method, declared in protocol_methods().items():
        declared_params = list(inspect.signature(declared).parameters.values())
        actual_params = list(inspect.signature(getattr(type(problem), method)).parameters.values())
        assert [(p.name, p.kind, p.default) for p in actual_params] == \
            [(p.name, p.kind, p.default) for p in declared_params], f"{name}.{method}"
    m = problem.measured.size
    assert problem.times.shape == problem.train.shape == problem.weights.shape == (m,)
    assert problem.config.compressibility == FOLLOWING["compressibility"]


def test_the_diagnosis_default_simulation_lets_the_sound_speed_follow_the_stir():
    # the fit's frozen path is taken on the diagnosis's defaults: the contract must hold there
    defaults = yaml.safe_load(open(f"{CONF_DIR}/diagnose.yaml"))["defaults"]
    assert {"sim": "coarse2d"} in defaults
    assert yaml.safe_load(open(f"{CONF_DIR}/sim/coarse2d.yaml"))["compressibility"] is not None


def test_a_replay_frozen_at_a_new_sound_speed_starts_an_empty_cache():
    replay = implementations()["CachedReplay"]
    material = replay.model.material
    replay.simulations = 3
    replay.cache[b"theta"] = np.zeros(1)
    frozen = replay.frozen(material)
    assert frozen is not replay and frozen.cache == {} and frozen.simulations == 3
    assert frozen.config.fixed_sound_speed == replay.problem.frozen(material).config.fixed_sound_speed
    assert frozen.frozen(material) is frozen  # its sound speed is held: nothing to freeze again
    np.testing.assert_array_equal(frozen.measured, replay.measured)


def test_a_fit_runs_through_a_cached_replay_whose_sound_speed_follows_the_stir():
    """The diagnosis's physics fits on its default simulation: ``fit_model`` holds one sound speed for the fit."""
    replay = implementations()["CachedReplay"]
    model = replay.model
    fit = fit_model(replay, model, max_iterations=1)
    assert np.isfinite(fit.predicted).all() and fit.evaluations >= 1 + model.size
    assert math.isfinite(fit.loss)


def test_a_fit_runs_through_a_joint_problem_whose_sound_speed_follows_the_stir():
    joint = implementations()["JointProblem"]
    fit = fit_model(joint, FitModel.named("newtonian", eta=0.5), max_iterations=1)
    assert np.isfinite(fit.predicted).all() and fit.predicted.shape == joint.measured.shape


def test_a_stir_problem_freezes_once():
    stir = implementations()["StirProblem"]
    frozen = stir.frozen(Newtonian(eta=0.8))
    assert frozen is not stir and frozen.config.fixed_sound_speed > FOLLOWING["sound_speed"]
    assert frozen.frozen(Newtonian(eta=8.0)) is frozen
    assert replace(frozen.config, rollout_sound_speed=None) == stir.config
