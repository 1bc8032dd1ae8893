"""Candidate extensions of a fitted model: the physics a fit may have left out, each a model with parameters.

Every candidate refits the base law's viscosity scale s (a factor on each of its stress parameters, so
η(γ̇) → s η(γ̇)) beside its own parameters, so that it competes with the base law on equal terms; ``none`` is
the base law with s alone.

Sensor candidates act on the base law's simulated reading p(t) at the scale s (linearised in ln s through the
fit's Jacobian, p = p0 + J_s ln s, and re-anchored on a simulation where a fit moves s far,
``compare.ScaleReadings``), so they cost at most a simulation or two:

* ``sensor_lag``:       τ dy/dt = p − y (first-order response, beyond any the recording states)  τ [s]
* ``sensor_deadband``:  y = sign(p) max(|p| − d, 0) (readings below d lost)                d [N]
* ``sensor_drift``:     y = p + b0 + r (t − t0) (slow creep of the offset)                 b0 [N], r [N/s]
* ``inertia``:          y = p − m a_s(t): the sensor carries the rod and the fluid it drags along, so it also
                        reads the force m a that accelerates them; a_s is the rod's acceleration read through the
                        sensor mode (component or tangential only)                          m [kg]

Physics candidates change the simulated fluid or rig and are simulated (``diffstir.mpm.hidden_physics``):

* ``thixotropy``:        Moore structure λ, η = s η_law (1 + α λ), dλ/dt = (1 − λ)/t_r − k γ̇ λ, λ(0) = 1
                                                                                         α [1], k [1], t_r [s]
* ``viscoelasticity``:   Jeffreys polymer stress θ dτ_p/dt + τ_p = 2 β η dev D              θ [s], β [1]
* ``temperature_drift``: η = s η_law exp(−κ t), κ = b r (only the product of the sensitivity b [1/K] and the
                         warming rate r [K/s] shows in a force)                              κ [1/s]
* ``wall_slip``:         Navier slip at the rod, u_slip = b ∂u_t/∂n                          b [m]
* ``yield_stress``:      the law gains a yield stress: Newtonian → Bingham (τ_y, η_p), a power law or a
                         Carreau/Cross law → Herschel-Bulkley (τ_y, k, n); not applicable to a law that has one.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np
import torch
from torch import Tensor, nn

from ..fitting import FitModel, StirProblem, ThetaParameters, initial_model, lag_response, theta_of
from ..lab.sensor import dead_band
from ..mpm.hidden_physics import HiddenPhysics, TemperatureDrift, Thixotropy, Viscoelasticity
from ..recording import SensorSpec
from ..recording.sensor import sensor_reading_np
from ..rheology import RheologyLaw, make_law

#: Sensitivity b [1/K] through which the temperature candidate's κ = b r is simulated; any b gives the same force
#: for the same product, this one lets the simulator's rate bound (±1 K/s) span κ = ±0.5 1/s.
KAPPA_SENSITIVITY = 0.5

#: The yield-stress candidate's regularisation rate γ̇_c as a fraction of U/a [1].
YIELD_REGULARISATION = 0.1

#: The wall-slip candidate's starting slip lengths b as fractions of the rod's radius a [1], from a weak to a strong
#: slip, a factor 2 apart. Slip and the viscosity scale trade off along a valley of (s, b) whose floor the
#: Gauss-Newton steps barely follow (castor oil's 2 mm slip fitted at 1.15 mm from a single 1 mm start,
#: docs/diagnosis.md), so the fit starts from the best of them (``compare.screened_start``).
SLIP_STARTS = (0.025, 0.05, 0.1, 0.2, 0.4)

#: Laws that already have a yield stress.
YIELD_LAWS = ("bingham", "herschel_bulkley")


@dataclass(frozen=True)
class Param:
    """One fitted parameter: SI ``unit``, ``scale`` (``log``: θ = ln value; ``linear``: θ = value), bounds."""

    name: str
    unit: str
    scale: str
    lo: float
    hi: float

    def theta(self, value: float) -> float:
        """θ of the SI ``value``, clipped into the bounds first."""
        return theta_of(min(max(value, self.lo), self.hi), self.scale)


#: The base law's viscosity scale s [1], shared by every candidate.
SCALE = Param("viscosity_scale", "1", "log", 0.05, 20.0)


@dataclass
class Context:
    """What candidates need to know about the recording and the base fit, on the compared samples.

    Attributes:
        times: sample times [s], (M,).
        measured: readings [N], (M,).
        base_reading: the base law's simulated reading p0 [N], (M,).
        scale_column: d p / d ln s [N], (M,).
        accel_reading: the rod's acceleration read through the sensor mode [m/s²], (M,) (None: not linear).
        noise: the reading's noise level [N].
        shear_rate: U/a [1/s], the rod's mean speed over its radius.
        duration: the compared span [s].
        rebuild_time: the thixotropy candidate's starting rebuild time t_r [s].
        law: the base law.
        rod_radius: the rod's radius a [m].
    """

    times: np.ndarray
    measured: np.ndarray
    base_reading: np.ndarray
    scale_column: np.ndarray
    accel_reading: np.ndarray | None
    noise: float
    shear_rate: float
    duration: float
    rebuild_time: float
    law: RheologyLaw
    rod_radius: float

    @property
    def signal(self) -> float:
        """rms of the measured reading [N]."""
        return float(np.sqrt(np.mean(self.measured**2)))


def accel_reading(times: np.ndarray, velocity: np.ndarray, spec: SensorSpec) -> np.ndarray | None:
    """The rod's acceleration [m/s²] (central differences of ``velocity`` [m/s] (M, 2) over ``times`` [s]) read
    through the sensor mode; None where the reading is not linear in the force (magnitude, one-sided)."""
    if spec.mode == "magnitude" or spec.one_sided:
        return None
    accel = np.gradient(velocity, times, axis=0)
    return sensor_reading_np(accel, velocity, SensorSpec(mode=spec.mode, axis=spec.axis))


@dataclass(frozen=True)
class SensorCandidate:
    """An extension of the sensor model: ``reading(p, ctx, values)`` [N] of the base reading ``p`` [N] with the
    candidate's parameter ``values`` (SI, by name); ``starts(ctx)`` the starting values tried."""

    name: str
    params: tuple[Param, ...]
    reading: Callable[[np.ndarray, Context, dict], np.ndarray]
    starts: Callable[[Context], list[dict]]
    summary: str
    applies: Callable[[Context], str | None] = lambda ctx: None

    kind = "sensor"


@dataclass(frozen=True)
class PhysicsCandidate:
    """An extension of the simulated fluid or rig: ``starts(law, ctx)`` gives starting values (SI, by name; the
    fit screens them when there are several, ``compare.screened_start``) and ``material(law, values, ctx)`` the
    simulator material and the rod's slip length [m]."""

    name: str
    params: tuple[Param, ...]
    starts: Callable[[RheologyLaw, Context], list[dict]]
    material: Callable[[RheologyLaw, dict, Context], tuple[nn.Module, float]]
    summary: str

    kind = "physics"


def scaled_law(law: RheologyLaw, factor: float) -> RheologyLaw:
    """A copy of ``law`` with every stress parameter (unit in Pa) times ``factor``: η(γ̇) → factor η(γ̇)."""
    out = copy.deepcopy(law)
    bounds = out.bounds()
    values = {k: min(max(v * factor, bounds[k][0]), bounds[k][1])
              for k, v in out.parameters_si().items() if "Pa" in out.units[k]}
    out.set_parameters_si(**values)
    return out


def _scaled(physics: Callable[[RheologyLaw, dict, Context], nn.Module]):
    def material(law: RheologyLaw, values: dict, ctx: Context) -> tuple[nn.Module, float]:
        return physics(scaled_law(law, values["viscosity_scale"]), values, ctx), 0.0
    return material


SENSOR_CANDIDATES = {
    "sensor_lag": SensorCandidate(
        "sensor_lag", (Param("lag_time", "s", "log", 1e-3, 5.0),),
        lambda p, ctx, v: lag_response(p, ctx.times, v["lag_time"]),
        lambda ctx: [{"lag_time": tau} for tau in (0.01, 0.05, 0.2, 1.0)],
        "a first-order sensor response"),
    "sensor_deadband": SensorCandidate(
        "sensor_deadband", (Param("dead_band", "N", "linear", 0.0, 10.0),),
        lambda p, ctx, v: dead_band(p, v["dead_band"]),
        lambda ctx: [{"dead_band": f * ctx.signal} for f in (0.05, 0.2, 0.5)],
        "a sensor dead band (readings below a threshold lost)"),
    "sensor_drift": SensorCandidate(
        "sensor_drift", (Param("offset", "N", "linear", -10.0, 10.0),
                         Param("drift_rate", "N/s", "linear", -10.0, 10.0)),
        lambda p, ctx, v: p + v["offset"] + v["drift_rate"] * (ctx.times - ctx.times[0]),
        lambda ctx: [{"offset": 0.0, "drift_rate": 0.0}],
        "a creeping sensor offset"),
    "inertia": SensorCandidate(
        "inertia", (Param("moving_mass", "kg", "linear", 0.0, 10.0),),
        lambda p, ctx, v: p - v["moving_mass"] * ctx.accel_reading,
        # inside the bound m >= 0 (a start on it stalls the trust region): the mass whose m a is 10 % of the signal
        lambda ctx: [{"moving_mass": 0.1 * ctx.signal / max(float(np.sqrt(np.mean(ctx.accel_reading ** 2))), 1e-9)}],
        "the inertia of the rod and the fluid it carries (force m a at speed changes)",
        lambda ctx: None if ctx.accel_reading is not None else "needs a component or tangential, two-sided sensor"),
}


def _yield_law(law: RheologyLaw, ctx: Context) -> RheologyLaw:
    """The base law with a yield stress carrying a fifth of the stress at U/a (the identification's start shape):
    Newtonian → Bingham, any other law → Herschel-Bulkley. Its Papanastasiou regularisation rate is
    ``YIELD_REGULARISATION`` U/a: the force comes from the yielded flow near U/a, and a smaller rate only raises
    the unyielded viscosity τ_y/γ̇_c and with it the simulation's cost (the viscous time step ∝ 1/η)."""
    with torch.no_grad():
        eta = float(law(torch.tensor([ctx.shear_rate], dtype=torch.float64)).reshape(-1)[0])
    name = "bingham" if law.name == "newtonian" else "herschel_bulkley"
    params = initial_model(name, eta, ctx.shear_rate).params_si()
    return make_law(name, **params, shear_rate_reg=YIELD_REGULARISATION * ctx.shear_rate)


PHYSICS_CANDIDATES = {
    "thixotropy": PhysicsCandidate(
        "thixotropy", (SCALE, Param("alpha", "1", "log", 1e-2, 1e2), Param("breakdown", "1", "log", 1e-3, 10.0),
                       Param("rebuild_time", "s", "log", 0.05, 100.0)),
        lambda law, ctx: [{"viscosity_scale": 1.0 / 1.25, "alpha": 0.5, "breakdown": 0.1,
                           "rebuild_time": ctx.rebuild_time}],
        _scaled(lambda law, v, ctx: HiddenPhysics(
            law, thixotropy=Thixotropy(v["alpha"], v["breakdown"], v["rebuild_time"]), horizon=ctx.duration)),
        "thixotropy (viscosity that falls under shear and recovers at rest)"),
    "viscoelasticity": PhysicsCandidate(
        "viscoelasticity", (SCALE, Param("relaxation_time", "s", "log", 1e-3, 5.0),
                            Param("polymer_fraction", "1", "linear", 0.02, 0.98)),
        lambda law, ctx: [{"viscosity_scale": 1.0, "relaxation_time": 0.05, "polymer_fraction": 0.3}],
        _scaled(lambda law, v, ctx: HiddenPhysics(
            law, viscoelasticity=Viscoelasticity(v["relaxation_time"], v["polymer_fraction"]), horizon=ctx.duration)),
        "viscoelasticity (stress that relaxes with a time constant)"),
    "temperature_drift": PhysicsCandidate(
        "temperature_drift", (SCALE, Param("viscosity_drift_rate", "1/s", "linear", -0.5, 0.5)),
        lambda law, ctx: [{"viscosity_scale": 1.0, "viscosity_drift_rate": 0.0}],
        _scaled(lambda law, v, ctx: HiddenPhysics(
            law, temperature=TemperatureDrift(v["viscosity_drift_rate"] / KAPPA_SENSITIVITY, KAPPA_SENSITIVITY),
            horizon=ctx.duration)),
        "a viscosity drifting in time (temperature)"),
    "wall_slip": PhysicsCandidate(
        "wall_slip", (SCALE, Param("slip_length", "m", "log", 1e-5, 0.02)),
        lambda law, ctx: [{"viscosity_scale": 1.0, "slip_length": f * ctx.rod_radius} for f in SLIP_STARTS],
        lambda law, v, ctx: (scaled_law(law, v["viscosity_scale"]), v["slip_length"]),
        "wall slip (the fluid slides along the rod)"),
}

YIELD_SUMMARY = "a yield stress that the selected law lacks"

#: Every candidate name, in the order of the issue's vocabulary (``none`` is the base law alone).
CANDIDATES = ("sensor_lag", "sensor_deadband", "sensor_drift", "thixotropy", "viscoelasticity", "wall_slip",
              "temperature_drift", "yield_stress", "inertia", "none")


def check_names(names) -> list[str]:
    """The candidate ``names`` as a list, refusing unknown ones; ``none`` is always included."""
    names = list(names)
    unknown = sorted(set(names) - set(CANDIDATES))
    if unknown:
        raise ValueError(f"diagnose.candidates: unknown {unknown}; choose from {list(CANDIDATES)}")
    return names + ([] if "none" in names else ["none"])


class Parametrisation(ThetaParameters):
    """A candidate's parameters as θ (``fitting.ThetaParameters``: ln value for log-scaled, the value for linear
    ones), a ``fitting.ParameterSet`` for ``fitting.laplace``."""

    def __init__(self, params: tuple[Param, ...]):
        super().__init__([p.name for p in params], {p.name: p.unit for p in params}, [p.scale for p in params],
                         [(p.lo, p.hi) for p in params])
        self.params = params

    def theta_of(self, values: dict) -> np.ndarray:
        """θ of SI ``values`` (by name), each clipped into its bounds."""
        return np.array([p.theta(values[p.name]) for p in self.params])


class PhysicsModel(Parametrisation):
    """A physics candidate on top of the base law, seen by ``diffstir.fitting.fit_model`` as a model with θ (a
    ``fitting.MaterialParameters``): ``set_theta`` rebuilds ``material`` (and ``slip_length`` [m]) from θ."""

    is_baseline = False  # its viscosity does not depend on the simulation's step
    dt = None

    def __init__(self, candidate: PhysicsCandidate, law: RheologyLaw, ctx: Context):
        super().__init__(candidate.params)
        self.name, self.candidate, self.law, self.ctx = candidate.name, candidate, law, ctx
        self.set_theta(self.theta_of(candidate.starts(law, ctx)[0]))

    def theta(self) -> np.ndarray:
        return self._theta.copy()

    def set_theta(self, theta: np.ndarray) -> None:
        self._theta = np.clip(np.asarray(theta, dtype=np.float64), self.lower, self.upper)
        self.material, self.slip_length = self.candidate.material(self.law, self.values_of(self._theta), self.ctx)

    def params_si(self) -> dict[str, float]:
        return self.values_of(self._theta)


class CachedReplay:
    """A ``StirProblem`` whose simulations follow a candidate model (its material and the rod's slip length) and
    are cached by the model's θ, so that the finite-difference Jacobian taken before a fit and the fit itself
    never simulate the same θ twice. It is a ``fitting.FitProblem``; ``simulations`` counts its simulations."""

    def __init__(self, problem: StirProblem, model, simulations: int = 0):
        self.problem, self.model, self.cache, self.simulations = problem, model, {}, simulations
        self.train, self.measured, self.recording = problem.train, problem.measured, problem.recording
        self.times, self.weights = problem.times, problem.weights
        self.config, self.density = problem.config, problem.density

    def loss(self, predicted: np.ndarray, train: bool = True) -> float | None:
        return self.problem.loss(predicted, train)

    def frozen(self, material: nn.Module) -> "CachedReplay":
        """This replay, where its problem's sound speed is held already; else a replay of the problem frozen at
        ``material``'s sound speed (``StirProblem.frozen``), with an empty cache (its readings at a θ differ from
        this one's) and this one's count of simulations."""
        frozen = self.problem.frozen(material)
        return self if frozen is self.problem else CachedReplay(frozen, self.model, self.simulations)

    def simulate(self, material: nn.Module) -> Tensor:
        key = np.asarray(self.model.theta(), dtype=np.float64).tobytes()
        if key not in self.cache:
            problem = self.problem
            slip = getattr(self.model, "slip_length", 0.0)
            if slip > 0:
                problem = copy.copy(problem)
                problem.rig = replace(problem.rig, rod=replace(problem.rig.rod, slip_length=float(slip)))
            self.cache[key] = problem.simulate(material)
            self.simulations += 1
        return self.cache[key]


def yield_model(law: RheologyLaw, ctx: Context) -> FitModel | None:
    """The yield-stress candidate as a ``FitModel`` (None when ``law`` already has a yield stress)."""
    if law.name in YIELD_LAWS:
        return None
    return FitModel(_yield_law(law, ctx))
