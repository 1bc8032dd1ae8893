"""The declared interfaces: every material the simulator takes is a ``mpm.Material``, every parameter set the
fitting engine reads is a ``fitting.ParameterSet`` (``fitting.MaterialParameters`` where it makes a material), and
every problem the fitter takes is a ``fitting.FitProblem``. ``runtime_checkable`` looks only for the members'
names, so each implementation is checked member by member: present, and a method callable as the protocol
declares it."""

import inspect
import math

import numpy as np
import pytest
import torch
from torch import nn

from diffstir.behaviour.joint import JointProblem
from diffstir.diagnosis.candidates import SCALE, SENSOR_CANDIDATES, CachedReplay, Parametrisation
from diffstir.fitting import FitModel, FitProblem, MaterialParameters, ParameterSet, StirProblem
from diffstir.lab.blend import BlendMaterial
from diffstir.mpm import (Corotated, HiddenPhysics, KelvinVoigt, Material, SimConfig, StatefulMaterial,
                          StepDependentMaterial, StirringSimulator, TemperatureDrift, Thixotropy, Viscoelasticity,
                          as_material)
from diffstir.rheology import Carreau, Newtonian
from diffstir.rig import Rig
from test_fit_contract import implementations

TINY = SimConfig(dim=2, dx=0.005, sound_speed=2.0, dtype="float64", dt=1e-3)
PROTOCOL_INTERNALS = {"_is_protocol", "_is_runtime_protocol", "__protocol_attrs__", "__non_callable_proto_members__"}


def members(protocol) -> dict[str, object]:
    """The protocol's members by name, each as its most derived declaration (None for a bare annotation)."""
    found = {}
    for base in reversed(protocol.__mro__):
        if not getattr(base, "_is_protocol", False) or base.__module__ in ("typing", "typing_extensions"):
            continue
        for name in (*base.__dict__.get("__annotations__", {}), *base.__dict__):
            if not name.startswith("_") and name not in PROTOCOL_INTERNALS:
                found[name] = base.__dict__.get(name)
    return found


def assert_implements(obj, protocol) -> None:
    """``obj`` has each of ``protocol``'s members, and each method takes the declared parameters (of the same kind,
    by name) and needs no others."""
    assert isinstance(obj, protocol), f"{type(obj).__name__} is not a {protocol.__name__}"
    for name, declared in members(protocol).items():
        assert hasattr(obj, name), f"{type(obj).__name__} lacks {protocol.__name__}.{name}"
        if not inspect.isfunction(declared):
            continue
        wanted = {p.name: p.kind for p in list(inspect.signature(declared).parameters.values())[1:]}
        actual = inspect.signature(getattr(obj, name)).parameters
        for param, kind in wanted.items():
            assert param in actual, f"{type(obj).__name__}.{name} lacks the parameter {param}"
            takes = {actual[param].kind, inspect.Parameter.POSITIONAL_OR_KEYWORD}  # keyword-only: either kind
            assert kind in takes, f"{type(obj).__name__}.{name}({param}) is {actual[param].kind}, not {kind}"
        extra = [p for n, p in actual.items() if n not in wanted and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]
        assert all(p.default is not p.empty for p in extra), f"{type(obj).__name__}.{name} needs {extra}"


# --- materials -------------------------------------------------------------------------------------------------

def test_the_material_protocols_name_what_the_simulator_reads():
    assert set(members(Material)) == {"shear_stress", "max_viscosity"}
    assert set(members(StatefulMaterial)) == {"shear_stress", "max_viscosity", "initial_material_state"}
    assert set(members(StepDependentMaterial)) == {"shear_stress", "max_viscosity", "step_dependent"}


def law():
    return Newtonian(eta=0.5)


MATERIALS = {
    "KelvinVoigt": (lambda: KelvinVoigt(law()), Material),
    "Corotated": (lambda: Corotated(400.0), StepDependentMaterial),
    "HiddenPhysics": (lambda: HiddenPhysics(law(), thixotropy=Thixotropy(0.5, 0.1, 1.0),
                                            viscoelasticity=Viscoelasticity(0.05, 0.3),
                                            temperature=TemperatureDrift(0.01, 0.02)), StatefulMaterial),
    "BlendMaterial": (lambda: BlendMaterial(law(), Newtonian(eta=0.1), 1.0), StatefulMaterial),
}


@pytest.mark.parametrize("name", sorted(MATERIALS))
def test_every_material_implements_the_protocol(name):
    make, protocol = MATERIALS[name]
    material = make()
    assert_implements(material, protocol)
    assert isinstance(material, Material) and isinstance(material, nn.Module)
    assert as_material(material) is material


def test_only_the_corotated_baseline_depends_on_the_step():
    assert Corotated(400.0).step_dependent is True
    for name in ("KelvinVoigt", "HiddenPhysics", "BlendMaterial"):
        material = MATERIALS[name][0]()
        assert not (isinstance(material, StepDependentMaterial) and material.step_dependent)
    assert not StirringSimulator(Corotated(400.0), Rig(), TINY).subcycles
    assert StirringSimulator(law(), Rig(), TINY).subcycles


def test_a_law_becomes_the_kelvin_voigt_material():
    carreau = Carreau(eta0=1.0, eta_inf=0.01, lam=0.5, n=0.6)
    material = as_material(carreau)
    assert isinstance(material, KelvinVoigt) and material.law is carreau
    assert isinstance(StirringSimulator(carreau, Rig(), TINY).material, KelvinVoigt)


@pytest.mark.parametrize("fluid", [lambda rate: rate, nn.Linear(1, 1), 0.5])
def test_anything_else_is_refused_with_what_a_fluid_must_be(fluid):
    with pytest.raises(TypeError, match="rheology law or a material nn.Module"):
        as_material(fluid)


# --- parameter sets --------------------------------------------------------------------------------------------

def test_the_parameter_protocols_name_what_the_fitting_engine_reads():
    assert set(members(ParameterSet)) == {"names", "units", "scales", "lower", "upper", "size", "si_of_theta"}
    assert set(members(MaterialParameters)) - set(members(ParameterSet)) == {
        "name", "material", "is_baseline", "dt", "theta", "set_theta", "params_si"}


def parameter_sets():
    return {
        "FitModel law": (FitModel.named("carreau", eta0=1.0, eta_inf=0.01, lam=0.5, n=0.6), MaterialParameters),
        "FitModel corotated": (FitModel.named("corotated", dt=2e-3, shear_modulus=400.0), MaterialParameters),
        "PhysicsModel": (implementations()["CachedReplay"].model, MaterialParameters),
        "Parametrisation": (Parametrisation((SCALE,) + SENSOR_CANDIDATES["sensor_drift"].params), ParameterSet),
    }


@pytest.mark.parametrize("name", ["FitModel law", "FitModel corotated", "PhysicsModel", "Parametrisation"])
def test_every_parameter_set_implements_the_protocol(name):
    params, protocol = parameter_sets()[name]
    assert_implements(params, protocol)
    assert params.size == len(params.names) == len(params.scales) == params.lower.size == params.upper.size
    assert set(params.units) == set(params.names)
    theta = 0.5 * (params.lower + params.upper)
    si = params.si_of_theta(theta)
    assert np.allclose(si, [math.exp(t) if s == "log" else t for t, s in zip(theta, params.scales)])


def test_parametrisations_share_the_theta_maps():
    par = Parametrisation((SCALE,) + SENSOR_CANDIDATES["sensor_drift"].params)
    values = {"viscosity_scale": 2.0, "offset": -0.5, "drift_rate": 0.25}
    theta = par.theta_of(values)
    assert theta.tolist() == [math.log(2.0), -0.5, 0.25]
    assert par.values_of(theta) == pytest.approx(values, rel=1e-15)
    assert par.values_of([1e3, 1e3, -1e3]) == pytest.approx({"viscosity_scale": SCALE.hi, "offset": 10.0,
                                                             "drift_rate": -10.0}, rel=1e-12)


def test_only_the_corotated_model_is_the_baseline():
    baseline = FitModel.named("corotated", dt=2e-3, shear_modulus=400.0)
    assert baseline.is_baseline and baseline.copy().is_baseline
    assert not FitModel.named("newtonian", eta=0.5).is_baseline
    assert not implementations()["CachedReplay"].model.is_baseline
    eta, grad = baseline.viscosity(np.array([0.1, 1.0, 10.0]))
    assert eta == pytest.approx(400.0 * 2e-3, rel=1e-6) and grad == pytest.approx(np.ones((3, 1)), rel=1e-12)
    assert baseline.zero_shear_viscosity() == pytest.approx(400.0 * 2e-3, rel=1e-6)
    baseline.set_theta(np.array([math.log(1e4)]))
    assert baseline.params_si()["shear_modulus"] == pytest.approx(1e4, rel=1e-6)
    with pytest.raises(ValueError, match="time step dt"):
        FitModel.named("corotated")


@pytest.mark.parametrize("model", [FitModel.named("carreau", eta0=1.0, eta_inf=0.01, lam=0.5, n=0.6),
                                   FitModel.named("corotated", dt=2e-3, shear_modulus=400.0)])
def test_the_gradient_in_theta_chains_through_the_materials_parameters(model):
    """``theta_gradient`` turns d f / d (the material's parameters) into d f / d θ: for f = ln η(γ̇), the
    gradient that ``viscosity`` gives."""
    rate = 3.0
    params = list(model.material.parameters())
    if model.is_baseline:
        log_eta = torch.log(model.material.shear_modulus * model.dt)
    else:
        log_eta = torch.log(model.material(torch.tensor([rate], dtype=params[0].dtype))).sum()
    grads = torch.autograd.grad(log_eta, params)
    expected = model.viscosity(np.array([rate]))[1][0]
    np.testing.assert_allclose(model.theta_gradient(grads), expected, rtol=2e-3, atol=1e-6)


# --- problems --------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["StirProblem", "JointProblem", "CachedReplay"])
def test_every_problem_implements_the_protocol(name):
    problem = implementations()[name]
    assert type(problem) is {"StirProblem": StirProblem, "JointProblem": JointProblem,
                             "CachedReplay": CachedReplay}[name]
    assert set(members(FitProblem)) == {"config", "density", "recording", "times", "measured", "train", "weights",
                                        "loss", "simulate", "frozen"}
    assert_implements(problem, FitProblem)
